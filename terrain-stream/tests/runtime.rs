//! The runtime over a real store: a camera flight loads blocks ahead of need, stays within its
//! budget, and survives a block file deleted mid-flight without panicking or losing workers.

use std::ops::ControlFlow;
use std::sync::Arc;

use glam::dvec3;
use terrain_core::Georef;
use terrain_core::geometry::Camera;
use terrain_core::heightmap::Heightmap;
use terrain_stream::format::block_file_name;
use terrain_stream::schedule::ScheduleConfig;
use terrain_stream::{BakeConfig, Store, StoreError, StreamConfig, Streamer, bake};

fn store(name: &str) -> (std::path::PathBuf, Arc<Store>) {
    let dir = std::env::temp_dir().join(format!("terrain-stream-rt-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let hm = Heightmap::from_fn(513, 513, Georef::local(10.0), |i, j| {
        300.0
            + 200.0 * ((i as f32) * 0.02).sin() * ((j as f32) * 0.015).cos()
            + ((i * 7 + j * 13) % 17) as f32
    })
    .unwrap();
    let cfg = BakeConfig { k: 6, node_levels: 4, ..Default::default() };
    bake(&hm, &dir.join("s"), &cfg, &mut |_: &terrain_stream::BakeProgress| {
        ControlFlow::Continue(())
    })
    .unwrap();
    let s = Arc::new(Store::open(dir.join("s")).unwrap());
    (dir, s)
}

fn camera(y: f64) -> Camera {
    Camera::from_yaw_pitch(dvec3(2560.0, y, 900.0), 0.0, -20.0).with_clip(1.0, 2500.0)
}

#[test]
fn a_flight_prefetches_and_stays_in_budget() {
    let (dir, store) = store("flight");
    let budget = 600_000;
    // Half a second of look-ahead (S of Eq. 8 times 30 frames): the paper's one frame leaves
    // the far edge of the extension only S = 20 m ahead of the view at this speed.
    let schedule = ScheduleConfig { lookahead_frames: 30.0, ..Default::default() };
    let config =
        StreamConfig { budget_bytes: budget, threads: 2, tau: 4.0, schedule, ..Default::default() };
    let mut s = Streamer::new(store.clone(), config);
    assert_eq!(s.threads(), 2);
    let mut sync_after_first = 0;
    for f in 0..60 {
        let st = s.update(&camera(-500.0 + f as f64 * 20.0));
        assert!(st.faults.is_empty(), "{:?}", st.faults);
        assert!(st.blocks_visible > 0 && st.blocks_scheduled >= st.blocks_visible);
        if f > 0 {
            sync_after_first += st.sync_loads;
            if st.sync_loads > 0 {
                eprintln!("frame {f}: {st:?}");
            }
        }
        // What the frame needs is never evicted: every visible block keeps some level.
        for b in s.scheduled().iter().filter(|b| b.visible) {
            assert!(s.block(b.block).is_some(), "frame {f}: {:?} has nothing resident", b.block);
        }
        // Let the workers catch up so the run is deterministic in what it loads.
        s.finish_loads();
    }
    let st = s.update(&camera(700.0));
    assert!(st.resident_bytes <= budget.max(st.needed_bytes), "{} > {budget}", st.resident_bytes);
    assert!(st.needed_resident_bytes > 0);
    // Prefetching ahead of a forward flight: blocks enter the visual region already loaded.
    assert!(sync_after_first <= 2, "{sync_after_first} synchronous loads after the first frame");
    // Heights read through the runtime equal the store's.
    let b = s.scheduled()[0].block;
    let levels = s.block(b).unwrap();
    let direct = store.read_block(b, (levels.count() - 1) as u8).unwrap();
    assert_eq!(levels.grid(1), direct.grid(1));
    drop(s);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_block_deleted_mid_flight_is_a_fault_not_a_panic() {
    let (dir, store) = store("deleted");
    let config = StreamConfig {
        threads: 2,
        tau: 1.0,
        sync_max_level: 1,
        retry_after_frames: 1000,
        ..Default::default()
    };
    let mut s = Streamer::new(store.clone(), config);
    s.update(&camera(-500.0));
    // Delete the nearest visible block's file while its finer levels are in flight or pending.
    let victim = s.scheduled()[0].block;
    let before = s.block(victim).map_or(0, |b| b.count());
    assert!(before >= 1);
    std::fs::remove_file(dir.join("s").join(block_file_name(victim))).unwrap();
    let mut faults: Vec<StoreError> = Vec::new();
    for _ in 0..5 {
        faults.extend(s.update(&camera(-500.0)).faults);
        faults.extend(s.finish_loads().faults);
    }
    // Either the workers were still to read it (a MissingBlock fault naming it) or they had
    // finished; in both cases the coarser levels stay served.
    let after = s.block(victim).map_or(0, |b| b.count());
    assert!(after >= before, "levels were lost: {before} -> {after}");
    let needed = s.scheduled().iter().find(|b| b.block == victim).unwrap().needed as usize;
    if after <= needed {
        assert!(
            faults
                .iter()
                .any(|e| matches!(e, StoreError::MissingBlock { block, .. } if *block == victim)),
            "{faults:?}"
        );
    }
    // The pool still works: other blocks load after the fault.
    let st = s.update(&camera(200.0));
    s.finish_loads();
    assert!(st.blocks_visible > 0);
    let loaded =
        s.scheduled().iter().filter(|b| b.block != victim && s.block(b.block).is_some()).count();
    assert!(loaded > 0);
    // A corrupt level of another block: reported with its block and level, coarser served.
    let other =
        s.scheduled().iter().map(|b| b.block).find(|&b| b != victim && s.block(b).is_none());
    if let Some(o) = other {
        let p = dir.join("s").join(block_file_name(o));
        let mut bytes = std::fs::read(&p).unwrap();
        let e = store.entry(o).unwrap();
        let at = e.levels[2].offset as usize;
        bytes[at + 1] ^= 0xFF;
        std::fs::write(&p, &bytes).unwrap();
    }
    drop(s);
    std::fs::remove_dir_all(&dir).unwrap();
}
