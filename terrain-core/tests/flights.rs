//! Every shipped flight in `flights/` loads on the default terrain and on a real DEM, with the
//! right frame count, finite cameras above the terrain and inside the DEM.

mod common;

use common::{data_dir, workspace};

use terrain_core::Heightmap;
use terrain_core::dem::{LoadOptions, load};
use terrain_core::flight::{FlightConfig, FlightSpec, frame_count};
use terrain_core::synth::default_terrain;

const SHIPPED: [(&str, f64); 9] = [
    ("pvps_884", 60.0),
    ("pvps_1012", 60.0),
    ("pvps_1140", 60.0),
    ("pvps_1268", 60.0),
    ("dss_approach", 30.0),
    ("valley_low", 30.0),
    ("overview_high", 40.0),
    ("fast_pass", 10.0),
    ("straight_down", 20.0),
];

fn check_all(hm: &Heightmap, what: &str) {
    let cfg = FlightConfig::default();
    let lo = hm.grid_to_world(0.0, 0.0);
    let hi = lo + hm.extent_m();
    for (name, duration) in SHIPPED {
        let spec = FlightSpec::load(workspace().join("flights").join(format!("{name}.json")))
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(spec.name, name);
        let (flight, _warnings) = spec.resolve(hm, &cfg);
        assert_eq!(flight.duration(), duration, "{name}");
        assert_eq!(flight.frames().len(), frame_count(duration, 30.0), "{name} on {what}");
        assert_eq!(flight.frames().len(), (duration * 30.0) as usize, "{name} on {what}");
        for (k, c) in flight.frames().iter().enumerate() {
            assert!(c.position.is_finite() && c.orientation.is_finite(), "{name} frame {k}");
            let p = c.position.truncate();
            assert!(p.cmpge(lo).all() && p.cmple(hi).all(), "{name} frame {k} outside: {p}");
            let ground = f64::from(hm.sample_world(p));
            assert!(c.position.z >= ground + cfg.clearance_m - 1e-6, "{name} frame {k} low");
        }
    }
    // The PVPS flights rise with the paper's heights.
    let mean_z = |name: &str| {
        let spec = FlightSpec::load(workspace().join(format!("flights/{name}.json"))).unwrap();
        let (f, _) = spec.resolve(hm, &cfg);
        f.keyframes.iter().map(|k| k.position.z).sum::<f64>()
    };
    assert!(mean_z("pvps_884") < mean_z("pvps_1012"));
    assert!(mean_z("pvps_1140") < mean_z("pvps_1268"));
}

#[test]
fn shipped_flights_on_the_default_terrain() {
    check_all(&default_terrain(), "default terrain");
}

#[test]
fn shipped_flights_on_a_real_dem() {
    // Non-square, projected, with voids.
    let dem = load(data_dir().join("big_tujunga/bigtujunga.tif"), &LoadOptions::default())
        .expect("big_tujunga loads (set TERRAIN_DATA)");
    check_all(&dem.heightmap, "big_tujunga");
}

#[test]
fn dss_approach_looks_at_the_peak_and_closes_in() {
    let hm = default_terrain();
    let spec = FlightSpec::load(workspace().join("flights/dss_approach.json")).unwrap();
    let (f, _) = spec.resolve(&hm, &FlightConfig::default());
    let (mut best, mut peak) = (f32::MIN, (0, 0));
    for j in 0..hm.height() {
        for i in 0..hm.width() {
            if hm.get(i, j) > best {
                best = hm.get(i, j);
                peak = (i, j);
            }
        }
    }
    let peak = hm.grid_to_world(peak.0 as f64, peak.1 as f64).extend(f64::from(best));
    let frames = f.frames();
    let d0 = (frames[0].position - peak).length();
    let d1 = (frames[frames.len() - 1].position - peak).length();
    assert!(d1 < d0 * 0.6, "{d0} -> {d1}");
    for k in [0, 300, 600] {
        let c = &frames[k];
        assert!((c.forward() - (peak - c.position).normalize()).length() < 1e-9, "frame {k}");
    }
}

/// A flight with an absurd fps or end time is refused when read, naming the file and the
/// fields, before any frame is computed (it used to ask for terabytes of cameras).
#[test]
fn absurd_flights_are_refused_when_read() {
    use terrain_core::flight::{FlightError, MAX_FRAMES};
    let tmp = common::temp_dir("terrain-core-flights-");
    let dir = tmp.path();
    let flight = |fps: &str, end: &str| {
        format!(
            r#"{{"name":"x","fps":{fps},"keyframes":[
                {{"t":0,"relative":[0.2,0.2,0.5],"yaw":0,"pitch":-10}},
                {{"t":{end},"relative":[0.8,0.8,0.5],"yaw":90,"pitch":-10}}]}}"#
        )
    };
    for (name, fps, end) in [("fast.json", "1e9", "60"), ("long.json", "30", "1e12")] {
        let p = dir.join(name);
        std::fs::write(&p, flight(fps, end)).unwrap();
        let e = FlightSpec::load(&p).unwrap_err();
        let FlightError::TooManyFrames { path, frames, max, .. } = &e else {
            panic!("{name}: expected TooManyFrames, got {e}");
        };
        assert_eq!(path.as_deref(), Some(p.as_path()));
        assert_eq!(*max, MAX_FRAMES);
        assert!(*frames >= 6e10, "{frames}");
        let msg = e.to_string();
        for want in [name, "fps", "\"t\"", &MAX_FRAMES.to_string()] {
            assert!(msg.contains(want), "{msg} lacks {want}");
        }
    }
    // Exactly MAX_FRAMES frames is allowed, one more is not.
    let at = |fps: f64| FlightSpec::parse(&flight(&fps.to_string(), "1000"));
    assert!(at(MAX_FRAMES as f64 / 1000.0).is_ok());
    assert!(matches!(
        at((MAX_FRAMES + 1) as f64 / 1000.0),
        Err(FlightError::TooManyFrames { path: None, .. })
    ));
}
