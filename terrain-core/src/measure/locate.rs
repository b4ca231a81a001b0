//! Point location in the drawn surface: a uniform grid over the mesh's triangles in plan
//! (grid coordinates), built once per frame, and the drawn height at a plan position.

use glam::DVec2;

use crate::lod::SurfaceMesh;

/// Barycentric tolerance: a point this far outside a triangle (in barycentric units) still
/// counts as inside, so samples on shared edges and vertices are always found.
const BARY_EPS: f64 = 1e-9;

/// A uniform bin grid over the non-degenerate triangles of a [`SurfaceMesh`], in the mesh's
/// grid coordinates (fractional samples). Bins are about one triangle's area, so a lookup
/// tests a handful of triangles.
#[derive(Debug)]
pub struct TriangleGrid<'m> {
    mesh: &'m SurfaceMesh,
    lo: DVec2,
    inv_cell: f64,
    nx: usize,
    ny: usize,
    /// CSR: triangles of bin `b` are `tris[start[b]..start[b + 1]]`.
    start: Vec<u32>,
    tris: Vec<u32>,
}

impl<'m> TriangleGrid<'m> {
    /// Bins every triangle of non-zero plan area by its plan bounding box.
    pub fn new(mesh: &'m SurfaceMesh) -> Self {
        let g = &mesh.grid;
        let live: Vec<u32> = (0..mesh.triangles.len() as u32)
            .filter(|&t| {
                let [a, b, c] = mesh.triangles[t as usize].map(|k| g[k as usize]);
                (b - a).perp_dot(c - a) != 0.0
            })
            .collect();
        let (mut lo, mut hi) = (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY));
        for &t in &live {
            for k in mesh.triangles[t as usize] {
                lo = lo.min(g[k as usize]);
                hi = hi.max(g[k as usize]);
            }
        }
        if live.is_empty() {
            return Self {
                mesh,
                lo: DVec2::ZERO,
                inv_cell: 1.0,
                nx: 0,
                ny: 0,
                start: vec![0],
                tris: Vec::new(),
            };
        }
        let size = (hi - lo).max(DVec2::splat(1e-9));
        let cell = (size.x * size.y / live.len() as f64).sqrt().max(1e-6);
        let nx = ((size.x / cell).ceil() as usize).clamp(1, 1 << 14);
        let ny = ((size.y / cell).ceil() as usize).clamp(1, 1 << 14);
        let inv_cell = 1.0 / cell;
        let mut grid = Self { mesh, lo, inv_cell, nx, ny, start: Vec::new(), tris: Vec::new() };
        // Two passes (count, fill): a CSR layout in triangle order, deterministic.
        let mut count = vec![0u32; nx * ny + 1];
        for &t in &live {
            grid.for_bins(t, |b| count[b] += 1);
        }
        let mut start = Vec::with_capacity(count.len());
        let mut acc = 0u32;
        for c in &count {
            start.push(acc);
            acc += c;
        }
        let mut fill = start.clone();
        let mut tris = vec![0u32; acc as usize];
        for &t in &live {
            grid.for_bins(t, |b| {
                tris[fill[b] as usize] = t;
                fill[b] += 1;
            });
        }
        grid.start = start;
        grid.tris = tris;
        grid
    }

    fn bin_range(&self, lo: f64, hi: f64, origin: f64, n: usize) -> (usize, usize) {
        let a = ((lo - origin) * self.inv_cell - 1e-9).floor().max(0.0) as usize;
        let b = ((hi - origin) * self.inv_cell + 1e-9).floor().max(0.0) as usize;
        (a.min(n - 1), b.min(n - 1))
    }

    fn for_bins(&self, t: u32, mut f: impl FnMut(usize)) {
        let [a, b, c] = self.mesh.triangles[t as usize].map(|k| self.mesh.grid[k as usize]);
        let (lo, hi) = (a.min(b).min(c), a.max(b).max(c));
        let (x0, x1) = self.bin_range(lo.x, hi.x, self.lo.x, self.nx);
        let (y0, y1) = self.bin_range(lo.y, hi.y, self.lo.y, self.ny);
        for y in y0..=y1 {
            for x in x0..=x1 {
                f(y * self.nx + x);
            }
        }
    }

    /// Height of the drawn surface at grid position `p` (linear inside the first triangle, in
    /// bin order, that contains it), or `None` where no triangle covers `p`.
    pub fn height_at(&self, p: DVec2) -> Option<f64> {
        if self.nx == 0 {
            return None;
        }
        let r = (p - self.lo) * self.inv_cell;
        if r.x < -1e-9 || r.y < -1e-9 || r.x > self.nx as f64 + 1e-9 || r.y > self.ny as f64 + 1e-9
        {
            return None;
        }
        let bx = (r.x.max(0.0) as usize).min(self.nx - 1);
        let by = (r.y.max(0.0) as usize).min(self.ny - 1);
        let b = by * self.nx + bx;
        let (g, pos) = (&self.mesh.grid, &self.mesh.positions);
        for &t in &self.tris[self.start[b] as usize..self.start[b + 1] as usize] {
            let [ia, ib, ic] = self.mesh.triangles[t as usize].map(|k| k as usize);
            let (a, bb, c) = (g[ia], g[ib], g[ic]);
            let d = (bb - a).perp_dot(c - a);
            let s = (p - a).perp_dot(c - a) / d;
            let u = (bb - a).perp_dot(p - a) / d;
            if s >= -BARY_EPS && u >= -BARY_EPS && 1.0 - s - u >= -BARY_EPS {
                return Some(pos[ia].z * (1.0 - s - u) + pos[ib].z * s + pos[ic].z * u);
            }
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{DVec3, dvec2};

    #[test]
    fn locates_points_on_vertices_edges_and_inside() {
        // Two triangles over the unit square, z = x + 2y; one degenerate triangle ignored.
        let grid = vec![dvec2(0.0, 0.0), dvec2(1.0, 0.0), dvec2(1.0, 1.0), dvec2(0.0, 1.0)];
        let positions = grid.iter().map(|g| DVec3::new(g.x, g.y, g.x + 2.0 * g.y)).collect();
        let mesh =
            SurfaceMesh { positions, grid, triangles: vec![[0, 1, 2], [0, 2, 3], [0, 0, 1]] };
        let tg = TriangleGrid::new(&mesh);
        for p in
            [dvec2(0.0, 0.0), dvec2(1.0, 1.0), dvec2(0.5, 0.5), dvec2(0.25, 0.7), dvec2(1.0, 0.3)]
        {
            let z = tg.height_at(p).unwrap();
            assert!((z - (p.x + 2.0 * p.y)).abs() < 1e-12, "{p}: {z}");
        }
        assert_eq!(tg.height_at(dvec2(1.5, 0.5)), None);
        assert_eq!(tg.height_at(dvec2(-0.01, 0.5)), None);
    }
}
