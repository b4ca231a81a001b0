//! Tests of the TIN pyramid and the quantized-mesh codec.

use glam::{DVec2, Vec3, dvec2};

use super::quantized_mesh::{self as qm, QmError};
use super::*;
use crate::georef::{Crs, Georef};
use crate::heightmap::VoidMask;
use crate::test_support::unit_rng;

/// A bumpy geographic grid (3 arc-seconds) whose origin is on no tile border, with a few voids.
fn bumpy(w: usize, h: usize, voids: bool) -> Heightmap {
    let spacing = DVec2::splat(1.0 / 1200.0);
    let origin = dvec2(-121.2871, 46.3313);
    let g = Georef::geographic(Crs::Epsg(4326), origin, spacing, origin.y + 0.05);
    let mut rng = unit_rng(7);
    let mut data = Vec::with_capacity(w * h);
    for j in 0..h {
        for i in 0..w {
            let (x, y) = (i as f64, j as f64);
            let z = 800.0 + 300.0 * (x * 0.11).sin() * (y * 0.07).cos() + 40.0 * rng();
            data.push(z as f32);
        }
    }
    let mut mask = VoidMask::new(w, h);
    if voids {
        for j in 30..40 {
            for i in 50..58 {
                mask.set(i, j, true);
                data[j * w + i] = 9000.0; // a fill no error may be measured against
            }
        }
    }
    Heightmap::new(w, h, data, mask, g).unwrap()
}

/// The mesh's height at `p` (tile unit square) and the number of triangles holding it,
/// found by brute force over every triangle (barycentric weights in f64, independent of the
/// builder's exact rasteriser).
fn height_at(mesh: &TileMesh, p: DVec2) -> (f64, usize) {
    let (mut z, mut hits) = (f64::NAN, 0);
    for t in &mesh.triangles {
        let [a, b, c] = t.map(|k| mesh.vertices[k as usize]);
        let d = (b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x);
        let w1 = ((p.x - a.x) * (c.y - a.y) - (p.y - a.y) * (c.x - a.x)) / d;
        let w2 = ((b.x - a.x) * (p.y - a.y) - (b.y - a.y) * (p.x - a.x)) / d;
        let w0 = 1.0 - w1 - w2;
        let eps = -1e-9;
        if w0 >= eps && w1 >= eps && w2 >= eps {
            z = w0 * a.z + w1 * b.z + w2 * c.z;
            hits += 1;
        }
    }
    (z, hits)
}

/// Every DEM sample inside `tile`: asserts `mesh` covers it and, unless it is a void, calls `f`
/// with the sample and the mesh's error there (metres). Returns how many samples `f` saw.
fn for_each_sample_error(
    hm: &Heightmap,
    grid: &GeoGrid<'_>,
    tile: TileId,
    mesh: &TileMesh,
    mut f: impl FnMut([usize; 2], f64),
) -> usize {
    let r = tile.rect();
    let mut seen = 0;
    for j in 0..hm.height() {
        for i in 0..hm.width() {
            let ll = grid.to_lonlat(dvec2(i as f64, j as f64));
            let p =
                dvec2((ll.x - r.west) / (r.east - r.west), (ll.y - r.south) / (r.north - r.south));
            if !(0.0..=1.0).contains(&p.x) || !(0.0..=1.0).contains(&p.y) {
                continue;
            }
            let (z, hits) = height_at(mesh, p);
            assert!(hits > 0, "{tile:?}: sample ({i}, {j}) not covered");
            if !hm.voids().get(i, j) {
                f([i, j], (z - f64::from(hm.get(i, j))).abs());
                seen += 1;
            }
        }
    }
    seen
}

/// Twice the total area of a tile mesh's triangles in the unit square.
fn area(mesh: &TileMesh) -> f64 {
    mesh.triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|k| mesh.vertices[k as usize]);
            (b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x)
        })
        .sum()
}

#[test]
fn every_tile_covers_its_rectangle_and_every_dem_sample_in_it_is_within_the_bound() {
    let hm = bumpy(241, 181, true);
    let grid = GeoGrid::new(&hm).unwrap();
    let e = grid.extent();
    let mut checked = 0usize;
    for level in [9u32, 11] {
        let bound = level_error(level, 0.25);
        let range = grid.tile_range(level);
        for tile in range.tiles(level) {
            let mesh = build_tile(&grid, tile, bound).unwrap();
            assert!((area(&mesh) - 2.0).abs() < 1e-9, "{tile:?}: twice the area {}", area(&mesh));
            assert!(mesh.triangles.iter().all(|t| {
                let [a, b, c] = t.map(|k| mesh.vertices[k as usize]);
                (b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x) > 0.0
            }));
            checked += for_each_sample_error(&hm, &grid, tile, &mesh, |at, err| {
                assert!(err <= bound + 1e-6, "{tile:?} {at:?}: {err} > {bound}");
            });
            // Outside the DEM the tile lies at height 0.
            for k in 0..mesh.vertices.len() {
                let ll = mesh.lonlat(k);
                let out = ll.x < e.west - 1e-9
                    || ll.x > e.east + 1e-9
                    || ll.y < e.south - 1e-9
                    || ll.y > e.north + 1e-9;
                if out {
                    assert_eq!(mesh.vertices[k].z, 0.0, "{tile:?} vertex {k} at {ll}");
                }
            }
        }
    }
    assert!(checked > 2 * 200 * 150, "{checked}");
}

#[test]
fn finer_levels_cost_more_triangles_and_a_tile_off_the_dem_is_two_flat_triangles() {
    let hm = bumpy(121, 121, false);
    let grid = GeoGrid::new(&hm).unwrap();
    let count = |level: u32| -> usize {
        grid.tile_range(level)
            .tiles(level)
            .map(|t| build_tile(&grid, t, level_error(level, 1.0)).unwrap().triangles.len())
            .sum()
    };
    let (coarse, fine) = (count(9), count(13));
    assert!(fine > 4 * coarse, "{coarse} -> {fine}");
    let off = build_tile(&grid, TileId { level: 0, x: 1, y: 0 }, 1.0).unwrap();
    assert_eq!(off.triangles.len(), 2);
    assert!(off.vertices.iter().all(|v| v.z == 0.0));
    assert!(off.measured.is_none());
    // The western root holds the DEM.
    let root = build_tile(&grid, TileId { level: 0, x: 0, y: 0 }, level_error(0, 1.0)).unwrap();
    assert!(root.measured.is_some());
    assert_eq!(grid.tile_range(0), TileRange { start_x: 0, start_y: 0, end_x: 0, end_y: 0 });
}

#[test]
fn projected_grids_are_refused_until_warped() {
    let hm = Heightmap::from_fn(
        8,
        8,
        Georef::projected(Crs::Epsg(32611), DVec2::ZERO, DVec2::ONE),
        |_, _| 0.0,
    )
    .unwrap();
    assert!(matches!(GeoGrid::new(&hm), Err(TinError::NotGeographic { .. })));
}

#[test]
fn zigzag_and_high_water_mark_round_trip() {
    for v in -32767..=32767 {
        assert_eq!(qm::unzigzag(qm::zigzag(v)), v);
    }
    assert_eq!([0, -1, 1, -2, 2].map(qm::zigzag), [0, 1, 2, 3, 4]);
    let mut rng = unit_rng(3);
    let mut idx = Vec::new();
    let mut next = 0u32;
    for _ in 0..3000 {
        if next == 0 || rng() < 0.3 {
            idx.push(next);
            next += 1;
        } else {
            idx.push((rng() * f64::from(next)) as u32);
        }
    }
    let codes = qm::hwm_encode(&idx).unwrap();
    assert_eq!(qm::hwm_decode(&codes), idx);
    assert!(qm::hwm_encode(&[0, 2, 1]).is_none(), "out of first-use order");
}

#[test]
fn oct_normals_round_trip_within_a_degree_and_a_half() {
    let mut rng = unit_rng(11);
    for _ in 0..5000 {
        let n =
            Vec3::new(rng() as f32 * 2.0 - 1.0, rng() as f32 * 2.0 - 1.0, rng() as f32 * 2.0 - 1.0);
        let Some(n) = n.try_normalize() else { continue };
        let back = qm::oct_decode(qm::oct_encode(n));
        let angle = n.dot(back).clamp(-1.0, 1.0).acos().to_degrees();
        assert!(angle < 1.5, "{n} -> {back}: {angle} degrees");
    }
    assert_eq!(qm::oct_encode(Vec3::Z), [128, 128]);
}

#[test]
fn tiles_round_trip_through_the_codec() {
    let hm = bumpy(241, 181, true);
    let grid = GeoGrid::new(&hm).unwrap();
    let level = 10;
    for tile in grid.tile_range(level).tiles(level) {
        let mesh = build_tile(&grid, tile, level_error(level, 0.25)).unwrap();
        let child = grid.tile_range(level + 1).below(tile);
        let bytes = qm::encode(&mesh, child).unwrap();
        let d = qm::decode(&bytes).unwrap();
        assert_eq!(d.triangles.len(), mesh.triangles.len(), "{tile:?}: no triangle collapses here");
        assert_eq!(d.vertices.len(), mesh.vertices.len());
        let q = f64::from(qm::QUANTIZED_MAX);
        let hq = f64::from(d.max_height - d.min_height) / q;
        // Every input vertex is found, quantized, among the decoded ones.
        let mut decoded: Vec<(DVec2, f64)> = (0..d.vertices.len()).map(|k| d.position(k)).collect();
        decoded.sort_by(|a, b| (a.0.x, a.0.y).partial_cmp(&(b.0.x, b.0.y)).unwrap());
        for v in &mesh.vertices {
            let uv = (dvec2(v.x, v.y) * q).round() / q;
            let k = decoded.partition_point(|(p, _)| (p.x, p.y) < (uv.x, uv.y));
            let (p, z) = decoded[k];
            assert!((p - uv).length() < 1e-12, "{tile:?}: {uv} not decoded");
            assert!((z - v.z).abs() <= 0.5 * hq + 1e-3, "{tile:?}: {z} vs {}", v.z);
        }
        // Edge lists hold exactly the vertices on each border.
        let max = qm::QUANTIZED_MAX as u16;
        let on: [&dyn Fn([u16; 3]) -> bool; 4] =
            [&|v| v[0] == 0, &|v| v[1] == 0, &|v| v[0] == max, &|v| v[1] == max];
        for (side, pred) in on.iter().enumerate() {
            let want: Vec<u32> =
                (0..d.vertices.len() as u32).filter(|&k| pred(d.vertices[k as usize])).collect();
            assert_eq!(d.edges[side], want, "{tile:?} side {side}");
            assert!(want.len() >= 2, "{tile:?} side {side}: a border has both its corners");
        }
        // Normals point up, away from the Earth's centre.
        let normals = d.normals.as_ref().unwrap();
        assert_eq!(normals.len(), d.vertices.len());
        let up = d.centre.normalize().as_vec3();
        // (Steep where the tile drops from the DEM to the ellipsoid beyond it, never downward.)
        assert!(normals.iter().all(|&n| qm::oct_decode(n).dot(up) > 0.0));
        let meta: serde_json::Value = serde_json::from_str(d.metadata.as_deref().unwrap()).unwrap();
        let avail = meta["available"].as_array().unwrap();
        assert_eq!(avail.len(), usize::from(child.is_some()));
        // The bounding sphere holds the vertices.
        let r = tile.rect();
        for k in 0..d.vertices.len() {
            let (p, z) = d.position(k);
            let e =
                qm::ecef(r.west + p.x * (r.east - r.west), r.south + p.y * (r.north - r.south), z);
            assert!(e.distance(d.sphere.0) <= d.sphere.1 * (1.0 + 1e-9) + 1e-3);
        }
    }
}

#[test]
fn corrupt_tiles_and_gzip_are_refused() {
    let hm = bumpy(61, 61, false);
    let grid = GeoGrid::new(&hm).unwrap();
    let tile = grid.tile_range(12).tiles(12).next().unwrap();
    let bytes = qm::encode(&build_tile(&grid, tile, 1.0).unwrap(), None).unwrap();
    assert!(matches!(qm::decode(&bytes[..bytes.len() / 2]), Err(QmError::Truncated { .. })));
    let gz = qm::gzip(&bytes);
    assert!(gz.len() < bytes.len());
    assert_eq!(qm::gunzip(&gz).unwrap(), bytes);
    let mut bad = gz.clone();
    let n = bad.len();
    bad[n - 6] ^= 1; // the CRC
    assert!(matches!(qm::gunzip(&bad), Err(QmError::Gzip(_))));
}

/// A grid in 0..360 longitudes wholly east of 180 is the same place 360 degrees west: its layout
/// is shifted there and tiles as the -180..180 grid does; one crossing 180 is refused, saying
/// to split it.
#[test]
fn longitudes_past_180_are_shifted_and_a_grid_across_180_is_refused() {
    let spacing = DVec2::splat(0.25);
    let geo = |west: f64| Georef::geographic(Crs::Epsg(4326), dvec2(west, 48.0), spacing, 49.0);
    let east = GridLayout::new(17, 9, &geo(234.0)).unwrap();
    let west = GridLayout::new(17, 9, &geo(-126.0)).unwrap();
    assert_eq!(east, west);
    assert_eq!(east.tile_range(6), west.tile_range(6));
    let e = GridLayout::new(17, 9, &geo(178.0)).unwrap_err();
    assert!(matches!(e, TinError::OutOfRange { .. }), "{e}");
    assert!(e.to_string().contains("split there"), "{e}");
}

/// A child seeded with its parent's vertices keeps them, stays within its bound at every DEM
/// sample inside it, and costs about the triangles of the unseeded child (the seeds only change
/// the order of insertion).
#[test]
fn a_child_seeded_with_its_parents_vertices_keeps_them_within_its_bound() {
    let hm = bumpy(241, 181, false);
    let grid = GeoGrid::new(&hm).unwrap();
    let (mut seeded_tris, mut plain_tris, mut kept) = (0usize, 0usize, 0usize);
    for parent in grid.tile_range(10).tiles(10) {
        let (_, seeds) = build_tile_seeded(&grid, parent, level_error(10, 0.25), &[]).unwrap();
        assert!(seeds.len() > 4, "{parent:?}: {} vertices", seeds.len());
        let Some(below) = grid.tile_range(11).below(parent) else { continue };
        for child in below.tiles(11) {
            let bound = level_error(11, 0.25);
            let (mesh, used) = build_tile_seeded(&grid, child, bound, &seeds).unwrap();
            let plain = build_tile(&grid, child, bound).unwrap();
            seeded_tris += mesh.triangles.len();
            plain_tris += plain.triangles.len();
            // Every seed inside the child's sub-grid became a vertex.
            // (The sub-grid: the box of the child's vertices, which hold its corners.)
            let lo = [0, 1].map(|k| used.iter().map(|v| v[k]).min().unwrap());
            let hi = [0, 1].map(|k| used.iter().map(|v| v[k]).max().unwrap());
            for s in &seeds {
                if (0..2).all(|k| (lo[k]..=hi[k]).contains(&s[k])) {
                    assert!(used.contains(s), "{child:?}: seed {s:?} is not a vertex");
                    kept += 1;
                }
            }
            // Within the bound at every DEM sample inside the tile.
            for_each_sample_error(&hm, &grid, child, &mesh, |at, e| {
                assert!(e <= bound + 1e-6, "{child:?}: sample {at:?} {e} m off, bound {bound}");
            });
        }
    }
    assert!(kept > 20, "{kept} seeds checked");
    let ratio = seeded_tris as f64 / plain_tris as f64;
    assert!((0.9..1.05).contains(&ratio), "{seeded_tris} seeded against {plain_tris} triangles");
}

/// A grid handed over whole gives the mesh its borrowed copy gives: meshed in place where the
/// tile's sub-grid is the whole grid (a window read for the tile), cropped where it is not or
/// where a void sample holds a non-finite height (which the crop makes 0).
#[test]
fn an_owned_grid_gives_the_mesh_of_a_borrowed_one() {
    let mut in_place = 0;
    for (voids, nan) in [(false, false), (true, false), (true, true)] {
        let hm = bumpy(241, 181, voids);
        let grid = GeoGrid::new(&hm).unwrap();
        for level in [9, 10] {
            for tile in grid.tile_range(level).tiles(level) {
                let bound = level_error(level, 0.25);
                // The tile's window, as `terrain tiles` reads it: the samples covering it.
                let Some([i0, j0, i1, j1]) = Placed::new(&grid.layout, tile).crop else {
                    continue;
                };
                let (ww, wh) = (i1 - i0 + 1, j1 - j0 + 1);
                let mut data = Vec::with_capacity(ww * wh);
                let mut mask = VoidMask::new(ww, wh);
                for j in 0..wh {
                    for i in 0..ww {
                        let void = hm.voids().get(i0 + i, j0 + j);
                        mask.set(i, j, void);
                        data.push(if void && nan { f32::NAN } else { hm.get(i0 + i, j0 + j) });
                    }
                }
                let origin = grid.to_lonlat(dvec2(i0 as f64, j0 as f64));
                let spacing = hm.georef().native_spacing;
                let g = Georef::geographic(Crs::Epsg(4326), origin, spacing, origin.y);
                let window = Heightmap::new(ww, wh, data, mask, g).unwrap();
                let borrowed = GeoGrid::new(&window).unwrap();
                let want = build_tile_seeded(&borrowed, tile, bound, &[]).unwrap();
                let whole =
                    Placed::new(&borrowed.layout, tile).crop == Some([0, 0, ww - 1, wh - 1]);
                let has_nan = window.data().iter().any(|z| !z.is_finite());
                in_place += usize::from(whole && !has_nan);
                let got = build_tile_owned(window, tile, bound, &[], Algorithm::Delaunay).unwrap();
                assert_eq!(got, want, "{tile:?}");
            }
        }
    }
    assert!(in_place >= 8, "{in_place} tiles meshed in place");
}

/// An RTIN tile (`Algorithm::Rtin`, `terrain tiles --mesher rtin`) is within its bound at every
/// DEM sample inside the tile, found by brute force over its triangles, voids skipped; it takes
/// no seeds, and it costs more triangles than the greedy tile at the same bound. Negative
/// control: at a tenth of its bound the RTIN tile breaks the bound somewhere.
#[test]
fn an_rtin_tile_is_within_its_bound_at_every_sample() {
    let hm = bumpy(241, 181, true);
    let grid = GeoGrid::new(&hm).unwrap();
    let (mut rtin_tris, mut greedy_tris, mut worst_over_tenth) = (0usize, 0usize, 0.0f64);
    let mut tiles = 0;
    for tile in grid.tile_range(11).tiles(11) {
        let bound = level_error(11, 1.0);
        let Some([i0, j0, i1, j1]) = Placed::new(&grid.layout, tile).crop else { continue };
        let window = crop(&hm, i0, j0, i1, j1);
        let origin = grid.to_lonlat(dvec2(i0 as f64, j0 as f64));
        let g = Georef::geographic(Crs::Epsg(4326), origin, hm.georef().native_spacing, origin.y);
        let window = window.with_georef(g);
        let (rtin, used) =
            build_tile_owned(window.clone(), tile, bound, &[[3, 3]], Algorithm::Rtin).unwrap();
        let (greedy, _) = build_tile_owned(window, tile, bound, &[], Algorithm::Delaunay).unwrap();
        assert!(!used.is_empty());
        rtin_tris += rtin.triangles.len();
        greedy_tris += greedy.triangles.len();
        tiles += 1;
        for_each_sample_error(&hm, &grid, tile, &rtin, |at, e| {
            assert!(e <= bound + 1e-6, "{tile:?}: sample {at:?} {e} m off, bound {bound}");
            worst_over_tenth = worst_over_tenth.max(e / (0.1 * bound));
        });
    }
    assert!(tiles >= 4, "{tiles} tiles");
    assert!(worst_over_tenth > 1.0, "a tenth of the bound holds too: the check proves nothing");
    assert!(rtin_tris > greedy_tris, "{rtin_tris} RTIN against {greedy_tris} greedy triangles");
}

/// Every edge of `mesh` used by one triangle only lies on the tile's border: no crack and no
/// T-junction inside the tile. The number of edges checked.
fn assert_conforming(mesh: &TileMesh) -> usize {
    let mut uses: std::collections::HashMap<(u32, u32), usize> = Default::default();
    for t in &mesh.triangles {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            *uses.entry((a.min(b), a.max(b))).or_default() += 1;
        }
    }
    let on_border = |a: DVec3, b: DVec3| {
        (a.x == b.x && (a.x == 0.0 || a.x == 1.0)) || (a.y == b.y && (a.y == 0.0 || a.y == 1.0))
    };
    for (&(a, b), &n) in &uses {
        let (pa, pb) = (mesh.vertices[a as usize], mesh.vertices[b as usize]);
        assert!(n <= 2, "{:?}: edge {pa} - {pb} in {n} triangles", mesh.tile);
        assert!(n == 2 || on_border(pa, pb), "{:?}: open edge {pa} - {pb}", mesh.tile);
    }
    uses.len()
}

/// Reads rectangles of `hm` for [`build_tile_read`], noting the most samples across one.
fn reader<'a>(
    hm: &'a Heightmap,
    largest: &'a std::cell::Cell<usize>,
) -> impl FnMut([usize; 4]) -> Result<(Vec<f32>, Option<VoidMask>), TinError> + 'a {
    move |[i0, j0, i1, j1]| {
        let (w, h) = (i1 - i0 + 1, j1 - j0 + 1);
        largest.set(largest.get().max(w.max(h)));
        let mut mask = VoidMask::new(w, h);
        let mut data = Vec::with_capacity(w * h);
        for j in 0..h {
            for i in 0..w {
                mask.set(i, j, hm.voids().get(i0 + i, j0 + j));
                data.push(hm.get(i0 + i, j0 + j));
            }
        }
        Ok((data, Some(mask)))
    }
}

/// A tile read by rectangles ([`build_tile_read`], the path of `terrain tiles`): with pieces
/// as large as the tile it is the mesh of the owned grid, exactly; in pieces of at most 24
/// cells it never holds more than a piece's samples, is within its bound at every DEM sample
/// inside it (brute force, voids skipped) and is conforming (pieces share their sides'
/// vertices). Negative control: the conformity check finds the open edges of a mesh with a
/// triangle removed.
#[test]
fn a_tile_read_in_pieces_is_within_its_bound_and_conforming() {
    let hm = bumpy(241, 181, true);
    let grid = GeoGrid::new(&hm).unwrap();
    let (mut pieced, mut edges) = (0, 0);
    for level in [10] {
        let bound = level_error(level, 0.25);
        for tile in grid.tile_range(level).tiles(level) {
            let largest = std::cell::Cell::new(0);
            let (whole, _) = build_tile_read(
                &grid.layout,
                tile,
                bound,
                &[],
                Algorithm::Delaunay,
                4096,
                reader(&hm, &largest),
            )
            .unwrap();
            let want =
                build_tile_owned(hm.clone(), tile, bound, &[], Algorithm::Delaunay).unwrap().0;
            assert_eq!(whole, want, "{tile:?}");
            let span = largest.get();
            let largest = std::cell::Cell::new(0);
            let (mesh, used) = build_tile_read(
                &grid.layout,
                tile,
                bound,
                &[[100, 90]],
                Algorithm::Delaunay,
                24,
                reader(&hm, &largest),
            )
            .unwrap();
            assert!(largest.get() <= 25, "{tile:?}: read {} samples across", largest.get());
            assert!(!used.is_empty());
            pieced += usize::from(span > 25);
            let seen = for_each_sample_error(&hm, &grid, tile, &mesh, |at, e| {
                assert!(e <= bound + 1e-6, "{tile:?}: sample {at:?} {e} m off, bound {bound}");
            });
            assert!(seen > 0);
            edges += assert_conforming(&mesh);
            assert_conforming(&whole);
            let mut holed = mesh.clone();
            holed.triangles.remove(holed.triangles.len() / 2);
            let caught = std::panic::catch_unwind(|| assert_conforming(&holed));
            assert!(caught.is_err(), "{tile:?}: a removed triangle left no open edge");
        }
    }
    assert!(pieced >= 2 && edges > 1000, "{pieced} tiles in pieces, {edges} edges");
}
