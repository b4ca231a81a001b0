//! Every synthetic hard case (flat, spike, cliff, sawtooth, plateau with voids, huge origin,
//! tiny, odd-sized, huge range) through loading, the quadtree and every error metric: results
//! are finite, and exact where the answer is known.

use std::path::PathBuf;

use glam::{DVec3, dvec3};
use terrain_core::dem::{self, Format, LoadOptions, RawSampleType, RawSpec};
use terrain_core::geometry::Camera;
use terrain_core::metrics::{Region, dss, geomorph, pvps, screen, static_error};
use terrain_core::quadtree::{FrustumCull, NoCull, Quadtree, SplitToLevel, select};
use terrain_core::synth::HardCase;
use terrain_core::{Georef, Heightmap};

/// Writes the case as a raw little-endian f32 file (north row first, voids as NaN) and reads it
/// back through the DEM loader, so every case also exercises the loading path.
fn through_raw_file(case: HardCase, hm: &Heightmap) -> Heightmap {
    // Removed when dropped, also when the test panics.
    let dir = tempfile::Builder::new().prefix("terrain-hard-cases-").tempdir().unwrap();
    let path: PathBuf = dir.path().join(format!("{}.f32", case.name()));
    let (w, h) = (hm.width(), hm.height());
    let mut bytes = Vec::with_capacity(w * h * 4);
    for j in (0..h).rev() {
        for i in 0..w {
            let z = if hm.voids().get(i, j) { f32::NAN } else { hm.get(i, j) };
            bytes.extend_from_slice(&z.to_le_bytes());
        }
    }
    std::fs::write(&path, &bytes).unwrap();
    let options = LoadOptions {
        format: Some(Format::Raw),
        raw: Some(RawSpec { width: w as u64, height: h as u64, sample: RawSampleType::F32 }),
        spacing_m: hm.georef().spacing_m.x,
        ..LoadOptions::default()
    };
    let loaded = dem::load(&path, &options).unwrap_or_else(|e| panic!("{}: {e}", case.name()));
    let back = loaded.heightmap;
    assert_eq!((back.width(), back.height()), (w, h), "{}", case.name());
    assert_eq!(
        back.voids().count(),
        hm.voids().count(),
        "{}: void count survives the file",
        case.name()
    );
    for j in 0..h {
        for i in 0..w {
            if !hm.voids().get(i, j) {
                assert_eq!(back.get(i, j), hm.get(i, j), "{} ({i},{j})", case.name());
            }
        }
    }
    // Raw files carry no georeference: put the case's own back for the rest of the test.
    back.with_georef(hm.georef().clone())
}

fn assert_finite(what: &str, v: f64) {
    assert!(v.is_finite(), "{what} is not finite: {v}");
}

/// Runs every metric over every node of a few levels and returns the root's static error.
fn every_metric(name: &str, hm: &Heightmap) -> f64 {
    let pyramid = static_error::StaticErrorPyramid::build(hm, 8);
    for level in 0..pyramid.levels() {
        for j in 0..pyramid.nodes_per_side(level) {
            for i in 0..pyramid.nodes_per_side(level) {
                assert_finite(
                    &format!("{name}: StaticE({level},{i},{j})"),
                    pyramid.get(level, i, j),
                );
                let region = pyramid.region(level, i, j);
                if level <= 2 {
                    assert_finite(name, static_error::node_error(hm, region).error);
                    let r = pvps::region_roughness(hm, region).0;
                    assert_finite(&format!("{name}: roughness"), r);
                    let ratio =
                        pvps::split_ratio(100.0, pvps::span(1000.0, level as u32), r, 1.0, 1.0);
                    assert!(!ratio.is_nan(), "{name}: PVPS ratio");
                }
            }
        }
    }
    let whole = Region::whole(hm);
    let d = dss::object_errors(hm, whole);
    for k in 0..dss::FACTORS {
        assert_finite(&format!("{name}: DSS avg f={}", dss::factor(k)), d.avg[k]);
        assert_finite(&format!("{name}: DSS max f={}", dss::factor(k)), d.max[k]);
    }
    let lambda = screen::lambda(720.0, 60f64.to_radians());
    for view in [dvec3(0.0, 1.0, -0.3), dvec3(0.0, 0.0, -1.0), dvec3(1.0, 0.0, 0.0)] {
        let rho = dss::screen_errors(&d.max, lambda, 500.0, view);
        assert!(rho.iter().all(|r| !r.is_nan()), "{name}: DSS screen error");
        let _ = dss::tessellation_factor(&rho, 1.0);
        assert!(
            !screen::sight_line_eq7(lambda, d.max[0], 500.0, view, dvec3(0.0, 1.0, -0.1)).is_nan()
        );
        assert!(!screen::plain(lambda, d.max[0], 0.0).is_nan(), "{name}: d = 0");
    }
    let patch =
        Region::new(0, 0, geomorph::PATCH_CELLS.min(hm.width().min(hm.height()) - 1).max(1));
    for l in geomorph::max_error_vertices(hm, patch, geomorph::Reference::FullResolution) {
        assert_finite(&format!("{name}: geomorph level {}", l.level), l.error);
    }
    pyramid.get(0, 0, 0)
}

fn quadtree_selections(name: &str, hm: &Heightmap) {
    let qt = Quadtree::new(hm, 1);
    let all = select(&qt, &mut SplitToLevel(qt.max_level()), &mut NoCull);
    let cells: u64 = all
        .iter()
        .map(|n| qt.clipped_rect(*n).unwrap())
        .map(|r| (r.x1 - r.x0) as u64 * (r.y1 - r.y0) as u64)
        .sum();
    assert_eq!(
        cells,
        ((hm.width() - 1) * (hm.height() - 1)) as u64,
        "{name}: leaves tile the grid"
    );
    // A camera above the middle of the terrain, looking north and down, in world coordinates.
    let mid = hm.grid_to_world((hm.width() - 1) as f64 / 2.0, (hm.height() - 1) as f64 / 2.0);
    let eye = DVec3::new(mid.x, mid.y - hm.extent_m().y, hm.max() as f64 + 1000.0);
    let cam = Camera::from_yaw_pitch(eye, 0.0, -30.0);
    let seen = select(&qt, &mut SplitToLevel(qt.max_level()), &mut FrustumCull::new(cam.frustum()));
    assert!(seen.len() <= all.len(), "{name}");
    for n in &seen {
        assert!(qt.node_info(*n).is_some(), "{name}: selected node {n:?} lies in the grid");
    }
}

#[test]
fn every_hard_case_loads_and_measures() {
    for &case in HardCase::all() {
        let built = case.build();
        let hm = through_raw_file(case, &built);
        let root_static = every_metric(case.name(), &hm);
        quadtree_selections(case.name(), &hm);
        match case {
            // A plane has zero error in every metric.
            HardCase::Flat => {
                assert_eq!(root_static, 0.0);
                let d = dss::object_errors(&hm, Region::whole(&hm));
                assert!(d.max.iter().all(|&e| e == 0.0));
            }
            // The root drops the spike (it keeps only its corners): the error is the spike's height.
            HardCase::Spike => assert_eq!(root_static, HardCase::SPIKE_HEIGHT as f64),
            HardCase::Cliff => assert!(root_static > 0.0),
            _ => {}
        }
    }
}

#[test]
fn metrics_at_a_huge_origin_equal_the_same_terrain_at_zero() {
    let far = HardCase::HugeOrigin.build();
    let (w, h, data, voids, _) = far.clone().into_parts();
    let near = Heightmap::new(w, h, data, voids, Georef::local(far.georef().spacing_m.x)).unwrap();
    let a = static_error::StaticErrorPyramid::build(&far, 6);
    let b = static_error::StaticErrorPyramid::build(&near, 6);
    for level in 0..a.levels() {
        for j in 0..a.nodes_per_side(level) {
            for i in 0..a.nodes_per_side(level) {
                let (x, y) = (a.get(level, i, j), b.get(level, i, j));
                assert!((x - y).abs() <= 1e-6 * x.abs().max(1.0), "({level},{i},{j}): {x} vs {y}");
            }
        }
    }
    // The same relative camera selects the same nodes.
    let pick = |hm: &Heightmap| {
        let qt = Quadtree::new(hm, 4);
        let c = hm.grid_to_world(100.0, 50.0);
        let cam = Camera::from_yaw_pitch(DVec3::new(c.x, c.y, 2500.0), 20.0, -25.0);
        select(&qt, &mut SplitToLevel(qt.max_level()), &mut FrustumCull::new(cam.frustum()))
    };
    assert_eq!(pick(&far), pick(&near));
}
