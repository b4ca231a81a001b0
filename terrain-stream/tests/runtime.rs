//! The runtime over a real store: a camera flight loads blocks ahead of need, stays within its
//! budget, and survives a block file deleted and a level corrupted mid-flight: typed faults
//! naming block and level, coarser levels still served, no panic, no worker lost.

use std::ops::ControlFlow;
use std::sync::Arc;

use glam::dvec3;
use terrain_core::Georef;
use terrain_core::geometry::Camera;
use terrain_core::heightmap::Heightmap;
use terrain_stream::format::block_file_name;
use terrain_stream::schedule::ScheduleConfig;
use terrain_stream::{
    BakeConfig, BlockId, ScheduledBlock, Store, StoreError, StreamConfig, Streamer, bake,
};

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

/// A small viewport (128 x 72): blocks a few km away need coarse levels for their shading
/// (`lod::shading_level`), so levels rise as the camera approaches.
fn camera(y: f64) -> Camera {
    Camera::from_yaw_pitch(dvec3(2560.0, y, 900.0), 0.0, -20.0)
        .with_viewport(128.0, 72.0)
        .with_clip(1.0, 2500.0)
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

/// The blocks of M and the level each needs for a camera sequence (a planning run: the
/// schedule depends on the cameras only, never on what is resident).
fn plan(store: &Arc<Store>, config: StreamConfig, cameras: &[Camera]) -> Vec<Vec<(BlockId, u8)>> {
    let mut s = Streamer::new(store.clone(), config);
    cameras
        .iter()
        .map(|c| {
            s.update(c);
            s.scheduled().iter().filter(|b| b.visible).map(|b| (b.block, b.needed)).collect()
        })
        .collect()
}

#[test]
fn a_block_deleted_mid_flight_is_a_fault_not_a_panic() {
    let (dir, store) = store("deleted");
    // Levels above 0 come only from the workers; every request of a frame is submitted at
    // once (no in-flight cap) and the budget never evicts, so what is resident after
    // `finish_loads` is exactly what the frames needed.
    let config = StreamConfig {
        threads: 2,
        tau: 3.0,
        sync_max_level: 0,
        max_in_flight: 10_000,
        retry_after_frames: 1000,
        ..Default::default()
    };
    // Frame A sees the south blocks from afar (coarse levels); frame B flies up to them (finer
    // levels); frame C turns to the north half of the map, which neither A nor B touched.
    let far = camera(-2000.0);
    let near = camera(-300.0);
    let north = Camera::from_yaw_pitch(dvec3(2560.0, 2600.0, 900.0), 0.0, -20.0)
        .with_viewport(128.0, 72.0)
        .with_clip(1.0, 2500.0);
    let planned = plan(&store, config, &[far, near]);
    // Victims: blocks visible in both frames whose needed level rises from A to B.
    let rising: Vec<(BlockId, u8, u8)> = planned[0]
        .iter()
        .filter_map(|&(b, la)| {
            let lb = planned[1].iter().find(|p| p.0 == b)?.1;
            (lb > la).then_some((b, la, lb))
        })
        .collect();
    assert!(rising.len() >= 2, "the flight must refine two blocks: {planned:?}");
    let (missing, missing_have, _) = rising[0];
    let (corrupt, corrupt_have, _) = rising[1];

    let mut s = Streamer::new(store.clone(), config);
    let st = s.update(&far);
    assert!(st.faults.is_empty(), "{:?}", st.faults);
    assert!(s.finish_loads().faults.is_empty());
    for (b, have) in [(missing, missing_have), (corrupt, corrupt_have)] {
        assert_eq!(s.block(b).map(|l| l.count()), Some(have as usize + 1), "{b}");
    }
    let grid_before = |s: &Streamer, b: BlockId, l: u8| s.block(b).unwrap().grid(l).unwrap();
    let missing_grid = grid_before(&s, missing, missing_have);
    let corrupt_grid = grid_before(&s, corrupt, corrupt_have);

    // Nothing is in flight: delete one block's file and corrupt the next level of another.
    std::fs::remove_file(dir.join("s").join(block_file_name(missing))).unwrap();
    let bad_level = corrupt_have + 1;
    let p = dir.join("s").join(block_file_name(corrupt));
    let mut bytes = std::fs::read(&p).unwrap();
    let le = store.entry(corrupt).unwrap().levels[bad_level as usize];
    bytes[(le.offset + le.len as u64 / 2) as usize] ^= 0x5A;
    std::fs::write(&p, &bytes).unwrap();

    let st = s.update(&near);
    let mut faults = st.faults;
    faults.extend(s.finish_loads().faults);
    // Exactly the two faults, typed, each naming its block and the first level it lacks.
    assert_eq!(faults.len(), 2, "{faults:?}");
    let missing_fault = faults
        .iter()
        .find(|e| matches!(e, StoreError::MissingBlock { .. }))
        .unwrap_or_else(|| panic!("no MissingBlock fault in {faults:?}"));
    assert_eq!(missing_fault.block(), Some(missing));
    assert_eq!(missing_fault.level(), Some(missing_have + 1));
    let msg = missing_fault.to_string();
    let names = |msg: &str, b: BlockId, l: u8| {
        msg.contains(&format!("row {}, col {}", b.row, b.col))
            && msg.contains(&format!("level {l}"))
    };
    assert!(names(&msg, missing, missing_have + 1), "{msg}");
    match faults.iter().find(|e| matches!(e, StoreError::Checksum { .. })) {
        Some(StoreError::Checksum { block, level, stored, computed, .. }) => {
            assert_eq!((*block, *level), (corrupt, bad_level));
            assert_eq!(*stored, le.crc32);
            assert_ne!(stored, computed);
        }
        _ => panic!("no checksum fault in {faults:?}"),
    }
    let msg = faults.iter().find(|e| e.block() == Some(corrupt)).unwrap().to_string();
    assert!(names(&msg, corrupt, bad_level) && msg.contains("checksum"), "{msg}");
    // The coarser resident levels still serve, unchanged, and nothing finer appeared.
    for (b, have, grid) in
        [(missing, missing_have, &missing_grid), (corrupt, corrupt_have, &corrupt_grid)]
    {
        let levels = s.block(b).unwrap();
        assert_eq!(levels.count(), have as usize + 1, "{b}");
        assert_eq!(levels.grid(have).as_ref(), Some(grid), "{b}");
        assert!(s.scheduled().iter().any(|x| x.block == b && x.visible && x.needed > have));
    }
    // Faulted blocks are not retried every frame (retry_after_frames): the fault is reported once.
    let st = s.update(&near);
    assert!(st.faults.is_empty(), "{:?}", st.faults);
    assert!(s.finish_loads().faults.is_empty());

    // The pool still serves later requests: both workers alive, the north blocks load to
    // levels only the workers load (sync_max_level is 0).
    assert_eq!(s.threads(), 2);
    let st = s.update(&north);
    assert!(st.faults.is_empty(), "{:?}", st.faults);
    assert!(st.requests > 0);
    let done = s.finish_loads();
    assert!(done.faults.is_empty(), "{:?}", done.faults);
    assert!(st.prefetched_bytes + done.prefetched_bytes > 0, "the workers delivered nothing");
    let fresh: Vec<&ScheduledBlock> = s
        .scheduled()
        .iter()
        .filter(|b| b.visible && !planned.iter().flatten().any(|p| p.0 == b.block))
        .collect();
    assert!(fresh.iter().any(|b| b.needed >= 1), "no worker-loaded level in {fresh:?}");
    for b in &fresh {
        let levels = s.block(b.block).unwrap();
        assert!(levels.count() > b.needed as usize, "{}", b.block);
    }
    drop(s);
    std::fs::remove_dir_all(&dir).unwrap();
}
