//! Exact line of sight from the eye to a DEM sample over the DEM's piecewise-linear grid-line
//! profile, with an early-out on the quadtree's per-node maximum heights.
//!
//! **The terrain the ray is tested against.** Along every grid line (`x = i` or `y = j`) the
//! terrain is the linear interpolation between the two samples the line passes between (the
//! bilinear surface restricted to grid lines). The ray from the eye to the sample is blocked
//! when, at any crossing with a grid line, the terrain is above the ray by more than
//! `epsilon_m`. This is a test at every grid-line crossing, not only at sample points (the
//! PVPS paper's section 2.2 samples the nearest DEM cell along a 3D Bresenham line, which can
//! miss a ridge between samples). Inside a cell the bilinear surface along the ray is
//! quadratic and may bulge above the ray between two crossings without either crossing
//! seeing it; that case (a ray grazing a saddle within one cell) is not tested.
//! Parts of the ray outside the grid see no terrain.

use glam::{DVec2, DVec3};

use crate::heightmap::Heightmap;
use crate::quadtree::{NodeId, Quadtree};

/// Line-of-sight queries against one heightmap and its quadtree.
#[derive(Debug, Clone, Copy)]
pub struct LineOfSight<'a> {
    hm: &'a Heightmap,
    qt: &'a Quadtree,
    epsilon_m: f64,
}

/// A ray in grid coordinates for x and y, metres for z: `e + t d`, `t` in `[0, 1]`.
#[derive(Debug, Clone, Copy)]
struct Ray {
    e: DVec3,
    d: DVec3,
}

impl Ray {
    fn z(&self, t: f64) -> f64 {
        self.e.z + t * self.d.z
    }
}

impl<'a> LineOfSight<'a> {
    /// Queries over `hm` with its quadtree `qt` (built from `hm`); terrain more than
    /// `epsilon_m` above the ray blocks it.
    pub fn new(hm: &'a Heightmap, qt: &'a Quadtree, epsilon_m: f64) -> Self {
        Self { hm, qt, epsilon_m }
    }

    /// Whether sample `(i, j)` (at its DEM height) is visible from `eye` (world frame).
    pub fn sample_visible(&self, eye: DVec3, i: usize, j: usize) -> bool {
        let g = self.hm.world_to_grid(eye.truncate());
        let target = DVec3::new(i as f64, j as f64, f64::from(self.hm.get(i, j)));
        let e = DVec3::new(g.x, g.y, eye.z);
        self.grid_visible(e, target)
    }

    /// Whether grid-space point `target` is visible from grid-space `eye` (x, y in samples,
    /// z in metres).
    pub fn grid_visible(&self, eye: DVec3, target: DVec3) -> bool {
        let ray = Ray { e: eye, d: target - eye };
        !self.blocked(NodeId::ROOT, &ray, 0.0, 1.0)
    }

    fn blocked(&self, n: NodeId, ray: &Ray, t0: f64, t1: f64) -> bool {
        let Some(info) = self.qt.node_info(n) else { return false };
        let r = info.rect;
        let lo = DVec2::new(r.x0 as f64, r.y0 as f64);
        let hi = DVec2::new(r.x1 as f64, r.y1 as f64);
        let Some((t0, t1)) = clip(ray, lo, hi, t0, t1) else { return false };
        // The ray is linear in t: its lowest point over [t0, t1] is at an end.
        let lowest = ray.z(t0).min(ray.z(t1));
        if info.aabb.max.z <= lowest + self.epsilon_m {
            return false;
        }
        if info.is_finest {
            return self.blocked_in_cells(ray, lo, hi, t0, t1);
        }
        n.children().into_iter().any(|c| self.blocked(c, ray, t0, t1))
    }

    /// Checks every grid-line crossing of the ray within `[t0, t1]` and the rectangle.
    fn blocked_in_cells(&self, ray: &Ray, lo: DVec2, hi: DVec2, t0: f64, t1: f64) -> bool {
        let hm = self.hm;
        let (w, h) = (hm.width(), hm.height());
        let eps = self.epsilon_m;
        // Crossings with vertical lines x = i: the terrain interpolates along y.
        if ray.d.x != 0.0 {
            let (xa, xb) = (ray.e.x + t0 * ray.d.x, ray.e.x + t1 * ray.d.x);
            let i0 = xa.min(xb).ceil().max(lo.x) as i64;
            let i1 = xa.max(xb).floor().min(hi.x) as i64;
            for i in i0..=i1 {
                let t = (i as f64 - ray.e.x) / ray.d.x;
                let y = ray.e.y + t * ray.d.y;
                if !(lo.y..=hi.y).contains(&y) {
                    continue;
                }
                let z = along_column(hm, i as usize, y, h);
                if z > ray.z(t) + eps {
                    return true;
                }
            }
        }
        // Crossings with horizontal lines y = j: the terrain interpolates along x.
        if ray.d.y != 0.0 {
            let (ya, yb) = (ray.e.y + t0 * ray.d.y, ray.e.y + t1 * ray.d.y);
            let j0 = ya.min(yb).ceil().max(lo.y) as i64;
            let j1 = ya.max(yb).floor().min(hi.y) as i64;
            for j in j0..=j1 {
                let t = (j as f64 - ray.e.y) / ray.d.y;
                let x = ray.e.x + t * ray.d.x;
                if !(lo.x..=hi.x).contains(&x) {
                    continue;
                }
                let z = along_row(hm, x, j as usize, w);
                if z > ray.z(t) + eps {
                    return true;
                }
            }
        }
        false
    }
}

/// Terrain height on the vertical grid line `x = i` at fractional row `y`.
pub(crate) fn along_column(hm: &Heightmap, i: usize, y: f64, h: usize) -> f64 {
    if h == 1 {
        return f64::from(hm.get(i, 0));
    }
    let j0 = (y.floor().max(0.0) as usize).min(h - 2);
    let f = y - j0 as f64;
    let (a, b) = (f64::from(hm.get(i, j0)), f64::from(hm.get(i, j0 + 1)));
    a + (b - a) * f
}

/// Terrain height on the horizontal grid line `y = j` at fractional column `x`.
pub(crate) fn along_row(hm: &Heightmap, x: f64, j: usize, w: usize) -> f64 {
    if w == 1 {
        return f64::from(hm.get(0, j));
    }
    let i0 = (x.floor().max(0.0) as usize).min(w - 2);
    let f = x - i0 as f64;
    let (a, b) = (f64::from(hm.get(i0, j)), f64::from(hm.get(i0 + 1, j)));
    a + (b - a) * f
}

/// Clips `[t0, t1]` of the ray's plan projection to the rectangle `lo..=hi` (slab test).
fn clip(ray: &Ray, lo: DVec2, hi: DVec2, mut t0: f64, mut t1: f64) -> Option<(f64, f64)> {
    for (e, d, a, b) in [(ray.e.x, ray.d.x, lo.x, hi.x), (ray.e.y, ray.d.y, lo.y, hi.y)] {
        if d == 0.0 {
            if e < a || e > b {
                return None;
            }
        } else {
            let (ta, tb) = ((a - e) / d, (b - e) / d);
            t0 = t0.max(ta.min(tb));
            t1 = t1.min(ta.max(tb));
        }
    }
    (t0 <= t1).then_some((t0, t1))
}
