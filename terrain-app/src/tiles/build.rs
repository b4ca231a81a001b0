//! One tile of `terrain tiles` from a [`Samples`] source, at the resolution its level needs,
//! the decimation error under a tile ([`decimation_error`]), and the check of a
//! coarse tile against every DEM sample under it ([`check`]). The decimation error and the
//! budget policy are the library's ([`terrain_app::decimation`], shared with the `tin` method).
//!
//! **Resolution per level.** A tile spanning `N` DEM samples is meshed from every `2^s`-th
//! sample, `s` the smallest with `N / 2^s <= max_cells` (cesium-terrain-builder resamples
//! every tile to a fixed grid the same way; we keep the DEM's own samples, which a store holds
//! as its levels). At `s = 0` the tile is [`tin::build_tile`] on the DEM's own samples, which
//! verifies it against every one of them. At `s > 0` it is meshed within a budget under its
//! bound against the decimated samples and then checked against every DEM sample under it
//! ([`check`]); the budgets and retries are [`super::walk`]'s. So every written tile is within
//! its bound of every non-void DEM sample, at any level, while the coarse levels read and mesh
//! a bounded number of samples.

use glam::{DVec2, dvec2};
use rayon::prelude::*;
use terrain_core::heightmap::VoidMask;
use terrain_core::tin::{self, GeoGrid, GridLayout, TileId, TileMesh};
use terrain_core::{Crs, Georef, Heightmap};

use terrain_app::decimation::{BudgetPolicy, Decimation};
use terrain_app::samples::Samples;

/// How tiles are sampled.
#[derive(Debug, Clone, Copy)]
pub(crate) struct ResolutionConfig {
    /// Most cells across a tile's mesh input before it is decimated.
    pub max_cells: usize,
    /// The budget a decimated tile gets, its retries and strides (the one policy both
    /// pyramids use).
    pub policy: BudgetPolicy,
}

impl Default for ResolutionConfig {
    fn default() -> Self {
        Self { max_cells: 256, policy: BudgetPolicy::default() }
    }
}

/// The tile's rectangle in fractional grid coordinates (south-west, north-east).
fn grid_rect(layout: &GridLayout, tile: TileId) -> (DVec2, DVec2) {
    let r = tile.rect();
    (layout.to_grid(dvec2(r.west, r.south)), layout.to_grid(dvec2(r.east, r.north)))
}

/// The DEM samples inside the tile (inclusive index ranges), or `None` if none is.
fn samples_inside(layout: &GridLayout, tile: TileId) -> Option<[usize; 4]> {
    let (a, b) = grid_rect(layout, tile);
    let (w, h) = (layout.width as f64 - 1.0, layout.height as f64 - 1.0);
    let i0 = (a.x - 1e-9).ceil().max(0.0);
    let j0 = (a.y - 1e-9).ceil().max(0.0);
    let i1 = (b.x + 1e-9).floor().min(w);
    let j1 = (b.y + 1e-9).floor().min(h);
    (i0 <= i1 && j0 <= j1).then_some([i0 as usize, j0 as usize, i1 as usize, j1 as usize])
}

/// The stride (log2) a tile is meshed at: the smallest `s` with at most `max_cells` cells
/// across at stride `2^s`.
pub(crate) fn stride_log2(layout: &GridLayout, tile: TileId, config: &ResolutionConfig) -> u32 {
    let (a, b) = grid_rect(layout, tile);
    let (w, h) = (layout.width as f64 - 1.0, layout.height as f64 - 1.0);
    let span = (b.x.min(w) - a.x.max(0.0)).max(b.y.min(h) - a.y.max(0.0)).max(0.0);
    let mut s = 0;
    while span / f64::from(1u32 << s) > config.max_cells as f64 && s < 30 {
        s += 1;
    }
    s
}

/// Builds `tile` from every `2^s`-th sample within `budget` metres of them (see the module
/// docs), seeded with the DEM samples `seeds` (`[i, j]`; those off the stride's lattice or
/// outside the window are skipped): the mesh, its `bound` set to `bound` (the tile's own), and
/// the DEM samples it took as vertices (its children's seeds).
pub(crate) fn build(
    samples: &dyn Samples,
    layout: &GridLayout,
    tile: TileId,
    s: u32,
    budget: f64,
    bound: f64,
    seeds: &[[u32; 2]],
) -> anyhow::Result<(TileMesh, Vec<[u32; 2]>)> {
    let (a, b) = grid_rect(layout, tile);
    let (w, h) = (layout.width, layout.height);
    let t = 1usize << s;
    // The window: every 2^s-th sample from the one at or before the tile's west (south)
    // border to the one at or after its east (north) border, clipped to the DEM (the last
    // may lie past it and reads the last column or row).
    let lo = |v: f64| ((v.floor().max(0.0) as usize) >> s) << s;
    let hi = |v: f64, n: usize| (v.ceil().min(n as f64 - 1.0).max(0.0) as usize).div_ceil(t) * t;
    let (i0, j0) = (lo(a.x).min(w - 1), lo(a.y).min(h - 1));
    let (i1, j1) = (hi(b.x, w).max(i0 + t), hi(b.y, h).max(j0 + t));
    let (ww, wh) = ((i1 - i0) / t + 1, (j1 - j0) / t + 1);
    let win = samples.window(i0, j0, ww, wh, s)?;
    let mut data = win.data;
    let voids = match win.voids {
        Some(m) if m.count() < ww * wh => {
            // A void may hold anything; the mesh's vertices need a finite height.
            for (k, z) in data.iter_mut().enumerate() {
                if m.get(k % ww, k / ww) && !z.is_finite() {
                    *z = 0.0;
                }
            }
            m
        }
        // Every sample void: they hold the readers' fill, taken as it is (as the builder does).
        _ => VoidMask::new(ww, wh),
    };
    let origin = layout.to_lonlat(dvec2(i0 as f64, j0 as f64));
    let spacing = layout.spacing * t as f64;
    let centre_lat = origin.y + 0.5 * (wh as f64 - 1.0) * spacing.y;
    let georef = Georef::geographic(Crs::Epsg(4326), origin, spacing, centre_lat);
    let sub = Heightmap::new(ww, wh, data, voids, georef)?;
    // The seeds on this window's lattice, in its coordinates.
    let on_lattice = |v: u32, v0: usize, n: usize| {
        let v = v as usize;
        (v >= v0 && (v - v0).is_multiple_of(t) && (v - v0) / t < n).then(|| ((v - v0) / t) as u32)
    };
    let local: Vec<[u32; 2]> = seeds
        .iter()
        .filter_map(|&[i, j]| Some([on_lattice(i, i0, ww)?, on_lattice(j, j0, wh)?]))
        .collect();
    let (mut mesh, used) = tin::build_tile_seeded(&GeoGrid::new(&sub)?, tile, budget, &local)?;
    mesh.bound = bound;
    let used =
        used.into_iter().map(|[i, j]| [(i0 + i as usize * t) as u32, (j0 + j as usize * t) as u32]);
    // The last row or column may stand past the DEM (read at its edge): not a DEM sample.
    let used = used.filter(|&[i, j]| (i as usize) < w && (j as usize) < h).collect();
    Ok((mesh, used))
}

/// The largest error of `mesh` against every non-void DEM sample under it, read by windows of
/// `region` x `region` cells in parallel (each window meets only the triangles binned to it);
/// `None` if the mesh leaves a sample uncovered (which the caller treats as a failure).
pub(crate) fn check(
    samples: &dyn Samples,
    layout: &GridLayout,
    mesh: &TileMesh,
    region: usize,
) -> anyhow::Result<Option<f64>> {
    let Some([ti0, tj0, ti1, tj1]) = samples_inside(layout, mesh.tile) else {
        return Ok(Some(0.0));
    };
    let tris = grid_triangles(layout, mesh);
    let (w, h) = (layout.width, layout.height);
    let (rx0, ry0) = (ti0 / region, tj0 / region);
    // A sample on a region border belongs to the region before it, except at the grid's edge.
    let last = |t: usize, n: usize| t.saturating_sub(1).min(n.saturating_sub(2)) / region;
    let (rx1, ry1) = (last(ti1, w).max(rx0), last(tj1, h).max(ry0));
    let (nx, ny) = (rx1 - rx0 + 1, ry1 - ry0 + 1);
    // Each triangle's index in every region its bounding box meets (with the scan's tolerance).
    let mut bins: Vec<Vec<u32>> = vec![Vec::new(); nx * ny];
    const EPS: f64 = 1e-7;
    let cell = |v: f64, r0: usize, n: usize| -> usize {
        ((v.max(0.0) / region as f64) as usize).clamp(r0, r0 + n - 1) - r0
    };
    for (k, t) in tris.iter().enumerate() {
        let (x0, x1) = (cell(t.lo.x - EPS, rx0, nx), cell(t.hi.x + EPS, rx0, nx));
        let (y0, y1) = (cell(t.lo.y - EPS, ry0, ny), cell(t.hi.y + EPS, ry0, ny));
        for y in y0..=y1 {
            for x in x0..=x1 {
                bins[y * nx + x].push(k as u32);
            }
        }
    }
    let worst = (0..nx * ny)
        .into_par_iter()
        .map(|r| -> anyhow::Result<Option<f64>> {
            let (i0, j0) = ((rx0 + r % nx) * region, (ry0 + r / nx) * region);
            let (i1, j1) = ((i0 + region).min(w - 1), (j0 + region).min(h - 1));
            let (x0, y0, x1, y1) = (ti0.max(i0), tj0.max(j0), ti1.min(i1), tj1.min(j1));
            if x0 > x1 || y0 > y1 {
                return Ok(Some(0.0));
            }
            let win = samples.window(x0, y0, x1 - x0 + 1, y1 - y0 + 1, 0)?;
            let at = |i: usize, j: usize| {
                let k = (j - y0) * win.width + (i - x0);
                let void = win.voids.as_ref().is_some_and(|v| v.get(i - x0, j - y0));
                (!void).then(|| win.data[k])
            };
            let mine: Vec<&Tri> = bins[r].iter().map(|&k| &tris[k as usize]).collect();
            Ok(max_error(&mine, [x0, y0, x1, y1], at))
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    Ok(worst.into_iter().try_fold(0f64, |a, e| e.map(|e| a.max(e))))
}

/// The decimation error at stride `2^s` over the regions under `tile` (0 for a tile without
/// samples): [`Decimation::error_in`] over the DEM samples inside it.
pub(crate) fn decimation_error(
    decimation: &Decimation,
    samples: &dyn Samples,
    layout: &GridLayout,
    tile: TileId,
    s: u32,
) -> anyhow::Result<f64> {
    match samples_inside(layout, tile) {
        Some(rect) => decimation.error_in(samples, rect, s),
        None => Ok(0.0),
    }
}

/// A triangle in grid coordinates with its plane.
struct Tri {
    p: [DVec2; 3],
    z0: f64,
    /// Height gradient per grid unit.
    g: DVec2,
    lo: DVec2,
    hi: DVec2,
}

fn grid_triangles(layout: &GridLayout, m: &TileMesh) -> Vec<Tri> {
    let (a, b) = grid_rect(layout, m.tile);
    let pos: Vec<(DVec2, f64)> = m
        .vertices
        .iter()
        .map(|v| (dvec2(a.x + v.x * (b.x - a.x), a.y + v.y * (b.y - a.y)), v.z))
        .collect();
    m.triangles
        .iter()
        .filter_map(|t| {
            let [(p0, z0), (p1, z1), (p2, z2)] = t.map(|k| pos[k as usize]);
            let (e1, e2) = (p1 - p0, p2 - p0);
            let d = e1.perp_dot(e2);
            if d <= 0.0 {
                return None;
            }
            // z = z0 + g . (q - p0), solved from the two edges.
            let g = dvec2(
                ((z1 - z0) * e2.y - (z2 - z0) * e1.y) / d,
                ((z2 - z0) * e1.x - (z1 - z0) * e2.x) / d,
            );
            Some(Tri { p: [p0, p1, p2], z0, g, lo: p0.min(p1).min(p2), hi: p0.max(p1).max(p2) })
        })
        .collect()
}

/// The largest `|mesh - sample|` over the samples `[i0, j0]..=[i1, j1]` that `at` gives
/// (`None`: void), `None` if a non-void one lies in no triangle. Each triangle is scanned row
/// by row over the samples inside it (edge functions with a tolerance of 1e-7 cells, so the
/// samples on shared edges count for both triangles).
fn max_error(
    tris: &[&Tri],
    [i0, j0, i1, j1]: [usize; 4],
    at: impl Fn(usize, usize) -> Option<f32>,
) -> Option<f64> {
    let (nw, nh) = (i1 - i0 + 1, j1 - j0 + 1);
    let mut covered = vec![false; nw * nh];
    let mut worst = 0f64;
    const EPS: f64 = 1e-7;
    for t in tris {
        if t.hi.x < i0 as f64 - EPS
            || t.lo.x > i1 as f64 + EPS
            || t.hi.y < j0 as f64 - EPS
            || t.lo.y > j1 as f64 + EPS
        {
            continue;
        }
        let ja = ((t.lo.y - EPS).ceil().max(j0 as f64)) as usize;
        let jb = ((t.hi.y + EPS).floor().min(j1 as f64)) as usize;
        for j in ja..=jb {
            let y = j as f64;
            // The x-interval where all three edge functions are >= -EPS (counter-clockwise).
            let (mut xa, mut xb) = (t.lo.x - EPS, t.hi.x + EPS);
            for k in 0..3 {
                let (p, q) = (t.p[k], t.p[(k + 1) % 3]);
                let e = q - p;
                // e x (x - p) = e.x (y - p.y) - e.y (x - p.x) >= -EPS |e|
                let c = e.x * (y - p.y) + e.y * p.x + EPS * e.length();
                // -e.y x + c >= 0
                if e.y > 0.0 {
                    xb = xb.min(c / e.y);
                } else if e.y < 0.0 {
                    xa = xa.max(c / e.y);
                } else if c < 0.0 {
                    xa = f64::INFINITY;
                }
            }
            let xa = xa.ceil().max(i0 as f64);
            let xb = xb.floor().min(i1 as f64);
            if xa > xb {
                continue;
            }
            for i in xa as usize..=xb as usize {
                covered[(j - j0) * nw + (i - i0)] = true;
                if let Some(z) = at(i, j) {
                    let q = dvec2(i as f64, y) - t.p[0];
                    let m = t.z0 + t.g.dot(q);
                    worst = worst.max((m - f64::from(z)).abs());
                }
            }
        }
    }
    for j in 0..nh {
        for i in 0..nw {
            if !covered[j * nw + i] && at(i0 + i, j0 + j).is_some() {
                return None;
            }
        }
    }
    Some(worst)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tri(p: [DVec2; 3], z: [f64; 3]) -> Vec<Tri> {
        let m = TileMesh {
            tile: TileId { level: 0, x: 0, y: 0 },
            vertices: p.iter().zip(z).map(|(p, z)| glam::DVec3::new(p.x, p.y, z)).collect(),
            triangles: vec![[0, 1, 2]],
            bound: 1.0,
            measured: None,
        };
        // A layout where tile 0/0/0 is the grid square 0..10 x 0..10.
        let layout = GridLayout {
            width: 11,
            height: 11,
            origin: dvec2(-180.0, -90.0),
            spacing: dvec2(18.0, 18.0),
        };
        grid_triangles(&layout, &m)
    }

    #[test]
    fn the_scan_measures_every_sample_and_finds_gaps() {
        // Two triangles covering the 0..10 square, the plane z = x; samples z = x + (i == 3).
        let mut t = tri([dvec2(0.0, 0.0), dvec2(1.0, 0.0), dvec2(1.0, 1.0)], [0.0, 10.0, 10.0]);
        t.extend(tri([dvec2(0.0, 0.0), dvec2(1.0, 1.0), dvec2(0.0, 1.0)], [0.0, 10.0, 0.0]));
        let at = |i: usize, j: usize| Some(i as f32 + if (i, j) == (3, 7) { 2.5 } else { 0.0 });
        let t: Vec<&Tri> = t.iter().collect();
        let e = max_error(&t, [0, 0, 10, 10], at).unwrap();
        assert!((e - 2.5).abs() < 1e-9, "{e}");
        // One triangle only: the samples above the diagonal are uncovered.
        assert_eq!(max_error(&t[..1], [0, 0, 10, 10], at), None);
        // ... unless they are void.
        let void_above = |i: usize, j: usize| (j <= i).then_some(i as f32);
        assert_eq!(max_error(&t[..1], [0, 0, 10, 10], void_above), Some(0.0));
    }
}
