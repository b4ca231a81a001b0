//! Running the benchmark: [`run_bench`] over flights, methods and sweep values, every frame
//! through the one frame loop ([`crate::method::FrameLoop`]: measured, and drawn when a GPU is
//! given), progress, timing notes.

use std::sync::Arc;
use std::time::Instant;

use glam::dvec2;
use terrain_core::Heightmap;
use terrain_core::flight::{FlightConfig, FlightSpec, FlightWarning};
use terrain_gpu::{GpuContext, RenderConfig};

use super::config::{BenchConfig, frame_indices, pick_evenly};
use super::record::{BenchReport, FlightInfo, RunRecord, RunSummary};
use crate::method::registry::{self, MethodOptions, apply_parameter, sweep_values};
use crate::method::{FrameLoop, FrameRenderer, OocWait, draws_from_store, store_method};
use crate::methods::{LodMethod, MethodScene};
use crate::ooc::OocScene;
use anyhow::Context;
use terrain_visibility::pvs::{PvsMode, write_pvs};

/// Progress of a benchmark: `done` of `total` frames, and what runs now.
#[derive(Debug, Clone, PartialEq)]
pub struct BenchProgress {
    /// Frames done.
    pub done: usize,
    /// Frames in all.
    pub total: usize,
    /// Flight, method and parameter now running.
    pub label: String,
}

/// A plain-text progress bar on stderr, rewritten in place on a terminal; elsewhere (a log, CI)
/// a plain line at each tenth of the frames, without carriage returns.
pub fn print_progress(p: &BenchProgress) {
    let width = 30;
    let filled = (p.done * width).checked_div(p.total).unwrap_or(width);
    if !crate::progress::on_terminal() {
        let tenth = |d: usize| (d * 10).checked_div(p.total).unwrap_or(10);
        if p.done == p.total || tenth(p.done) > tenth(p.done.saturating_sub(1)) {
            eprintln!("{}/{} frames: {}", p.done, p.total, p.label);
        }
        return;
    }
    eprint!(
        "\r[{}{}] {}/{} {:<40}",
        "#".repeat(filled),
        " ".repeat(width - filled),
        p.done,
        p.total,
        p.label
    );
    if p.done == p.total {
        eprintln!();
    }
}

/// Runs the benchmark on `hm` (named `terrain`) over `flights`, rendering with `gpu` when given.
pub fn run_bench(
    terrain: &str,
    hm: Heightmap,
    flights: &[FlightSpec],
    cfg: &BenchConfig,
    gpu: Option<&GpuContext>,
    progress: &mut dyn FnMut(&BenchProgress),
) -> anyhow::Result<BenchReport> {
    let grid = [hm.width(), hm.height()];
    let flight_cfg = FlightConfig {
        viewport_px: dvec2(f64::from(cfg.measure_viewport.0), f64::from(cfg.measure_viewport.1)),
        ..FlightConfig::default()
    };
    let resolved: Vec<_> = flights.iter().map(|f| f.resolve(&hm, &flight_cfg)).collect();
    let infos: Vec<FlightInfo> = resolved
        .iter()
        .map(|(f, w)| FlightInfo {
            name: f.name.clone(),
            total_frames: f.frames().len(),
            frames: frame_indices(f.frames().len(), cfg.max_frames),
            warnings: w.iter().map(FlightWarning::to_string).collect(),
        })
        .collect();

    let render_size = cfg.render_size.filter(|_| gpu.is_some());
    let render_config = render_size.map(|(width, height)| RenderConfig {
        width,
        height,
        background: [150, 185, 225, 255],
        ..Default::default()
    });
    let mut notes = timing_notes(gpu, render_config.is_some());
    notes.push(format!(
        "Pixel errors and DSS's rho_thr refer to a {}x{} view; frames per flight: {}.",
        cfg.measure_viewport.0,
        cfg.measure_viewport.1,
        if cfg.max_frames == 0 { "all".to_string() } else { format!("at most {}", cfg.max_frames) }
    ));
    notes.extend(cfg.methods.iter().filter_map(|&m| registry::note(m)).map(str::to_string));
    let mut scene = MethodScene::new(hm, cfg.method.clone());
    if let Some(dir) = &cfg.scene {
        for warning in crate::scene_files::load(&scene, dir, &cfg.methods) {
            eprintln!("warning: {warning}");
            notes.push(warning);
        }
    }
    if cfg.store_only {
        if cfg.ooc_store.is_none() {
            anyhow::bail!("a benchmark from the store only needs a baked store (ooc_store)");
        }
        if let Some(m) = cfg.methods.iter().find(|&&m| !draws_from_store(m)) {
            anyhow::bail!("{} does not draw from a store", m.name());
        }
    } else {
        scene.prepare(&cfg.methods);
    }
    let leaf_cells = scene.config.leaf_cells;
    let sweeps: Vec<(LodMethod, &'static str, Vec<f64>)> = cfg
        .methods
        .iter()
        .map(|&m| match &cfg.error_px {
            // One screen-error target for every method, mapped onto each one's parameter.
            Some(px) => (m, "error_px", px.clone()),
            None => {
                let (name, all) = sweep_values(m, leaf_cells);
                match cfg.sweep_override.iter().find(|(o, _)| *o == m) {
                    Some((_, given)) => (m, name, given.clone()),
                    None => (m, name, pick_evenly(&all, cfg.sweep_points)),
                }
            }
        })
        .collect();
    let error_view = registry::ErrorView {
        height_px: f64::from(cfg.measure_viewport.1),
        fov_y_deg: resolved
            .first()
            .and_then(|(f, _)| f.frames().first().map(|c| c.fov_y.to_degrees()))
            .unwrap_or(registry::ErrorView::REFERENCE.fov_y_deg),
    };
    let mut store: Option<Result<Arc<terrain_stream::Store>, String>> = None;
    // `ooc`'s settings with the chosen calibration of its store (prepared now for it).
    let mut ooc = cfg.ooc;
    if cfg.methods.contains(&LodMethod::OutOfCore) && cfg.error_px.is_some() {
        match store.get_or_insert_with(|| prepare_store(&scene.hm, cfg)) {
            Ok(s) => {
                ooc.calibration = cfg.ooc_calibration.resolve(s)?;
                notes.push(format!(
                    "ooc calibration: {}",
                    if ooc.tau_for_error_px(1.0).1 == crate::ooc_calibration::TauSource::Store {
                        "the store's"
                    } else {
                        "the shared one"
                    }
                ));
            }
            Err(e) => anyhow::bail!("the ooc method's store: {e}"),
        }
    }
    if let Some(targets) = &cfg.error_px {
        for &m in &cfg.methods {
            let mapped: Vec<String> = targets
                .iter()
                .map(|&px| {
                    let p = registry::params_for_error_px(m, px, error_view);
                    // The value the run applies (ooc's depends on its configured split rule).
                    let mut c = crate::methods::MethodConfig { ooc, ..Default::default() };
                    p.apply(&mut c);
                    let value = if m == LodMethod::OutOfCore { c.ooc.tau } else { p.value };
                    format!("{} px -> {} = {:.4}", px, p.parameter, value)
                })
                .collect();
            notes.push(format!("{} error_px: {}", m.name(), mapped.join(", ")));
        }
    }
    let mut done = 0;
    let mut runs = Vec::new();
    // Store faults already said (every run of a store meets the same ones).
    let mut faults_said = std::collections::BTreeSet::new();
    // Renderers that hold only the terrain, shared by every run that needs their kind.
    let mut shared: Vec<FrameRenderer> = Vec::new();
    // Each method from memory (or from the store when it needs one), then, with --from-store,
    // from the store when it can draw from one.
    let variants: Vec<(usize, bool)> = (0..sweeps.len())
        .flat_map(|k| {
            let m = sweeps[k].0;
            if cfg.store_only {
                // `ooc` is the store's own method; the others are drawn from it.
                return vec![(k, !registry::needs_store(m))];
            }
            let again = cfg.from_store && !registry::needs_store(m) && draws_from_store(m);
            std::iter::once((k, false)).chain(again.then_some((k, true))).collect()
        })
        .collect();
    let per_flight: usize = variants.iter().map(|&(k, _)| sweeps[k].2.len()).sum();
    let total: usize = infos.iter().map(|i| i.frames.len() * per_flight).sum();
    let mut tables_written = false;
    for ((flight, _), info) in resolved.iter().zip(&infos) {
        for &(k, from_store) in &variants {
            let (method, parameter, values) = &sweeps[k];
            // Store-backed methods: real time (every frame of the flight played at its rate,
            // only the first waits) unless --wait (every sampled frame waits; see the note).
            let ooc_wait = if cfg.ooc_wait { OocWait::EveryFrame } else { OocWait::FirstFrame };
            let mut options = MethodOptions { morph: true, store: None, ooc_wait };
            let on_store = registry::needs_store(*method) || from_store;
            let real_time = on_store && !cfg.ooc_wait;
            if on_store {
                match store.get_or_insert_with(|| prepare_store(&scene.hm, cfg)) {
                    Ok(s) => options.store = Some(s.clone()),
                    Err(e) => anyhow::bail!("the {} method's store: {e}", method.name()),
                }
            }
            // The temporary store gets the tables; a given store (`--scene`, `--ooc-store`) is
            // the user's and must hold them from its bake (the method says so otherwise).
            if from_store && !tables_written && cfg.ooc_store.is_none() {
                let dir = options.store.as_ref().expect("the store").dir().to_path_buf();
                write_tables(&scene, &cfg.methods, &dir)?;
                tables_written = true;
            }
            for &value in values {
                let mut config = cfg.method.clone();
                config.leaf_cells = leaf_cells;
                config.pvps.leaf_cells = leaf_cells;
                config.dss.leaf_cells = leaf_cells;
                // The flight's frames come at its own rate: Eq. 8's `f`.
                config.ooc = ooc.for_flight(flight.fps);
                if cfg.error_px.is_some() {
                    registry::params_for_error_px(*method, value, error_view).apply(&mut config);
                } else {
                    apply_parameter(&mut config, *method, value);
                }
                scene.config = config;
                let label = format!(
                    "{} {}{} {parameter}={value}",
                    info.name,
                    method.name(),
                    if from_store { " (store)" } else { "" }
                );
                let built = match (&options.store, from_store) {
                    (Some(store), true) => {
                        let runtime = OocScene::new(store.clone(), scene.config.ooc);
                        store_method(*method, runtime, &scene.config, ooc_wait, Some(&scene))?
                    }
                    _ => registry::build(*method, &scene, &options)?,
                };
                let mut own = None;
                let renderer = match (gpu, &render_config) {
                    (Some(ctx), Some(rc)) => {
                        let kind = built.renderer_kind();
                        if kind.shareable() {
                            let i = match shared.iter().position(|r| r.kind() == kind) {
                                Some(i) => i,
                                None => {
                                    shared.push(built.renderer(ctx, rc)?);
                                    shared.len() - 1
                                }
                            };
                            Some(&mut shared[i])
                        } else {
                            Some(own.insert(built.renderer(ctx, rc)?))
                        }
                    }
                    _ => None,
                };
                // Real time: a measured frame's measuring and drawing (seconds on a software
                // renderer) hold the store's I/O, so the workers get the flight's time only.
                let mut frames_loop = FrameLoop::new(built)
                    .measured(&scene.hm, &scene.qt, cfg.measure)
                    .rendered(renderer)
                    .holding_io(real_time)
                    .with_options(terrain_gpu::RenderOptions {
                        lod_colours: cfg.lod_colours,
                        ..Default::default()
                    });
                let cams = flight.frames();
                let mut frames = Vec::with_capacity(info.frames.len());
                // Real time: every frame at the flight's rate; a measured frame's held time
                // (its measuring and drawing, the I/O held) is taken off the clock, so the
                // next frame is due one period after its start plus that time. Otherwise the
                // sampled frames only.
                let played: Vec<usize> =
                    if real_time { (0..cams.len()).collect() } else { info.frames.clone() };
                let measured: std::collections::BTreeSet<usize> =
                    info.frames.iter().copied().collect();
                let period = std::time::Duration::from_secs_f64(1.0 / flight.fps.max(1e-3));
                let (mut clock, mut since, mut behind) = (Instant::now(), 0u32, 0usize);
                let mut streamed = Vec::new();
                for k in played {
                    if real_time {
                        match (clock + period * since).checked_duration_since(Instant::now()) {
                            Some(w) => std::thread::sleep(w),
                            None => behind += usize::from(since > 0),
                        }
                        since += 1;
                    }
                    if !measured.contains(&k) {
                        let stats = frames_loop.play(&cams[k])?;
                        streamed.extend(stats.stream);
                        continue;
                    }
                    let previous = k.checked_sub(1).filter(|_| cfg.popping).map(|p| &cams[p]);
                    let started = Instant::now();
                    let looped = frames_loop.frame(k, &cams[k], previous)?;
                    let record = looped.record;
                    streamed.extend(record.stream.clone());
                    frames.push(record);
                    done += 1;
                    progress(&BenchProgress { done, total, label: label.clone() });
                    (clock, since) = (started + looped.held, 1);
                }
                for fault in streamed.iter().flat_map(|s| &s.new_faults) {
                    if faults_said.insert(fault.clone()) {
                        eprintln!("warning: store fault: {fault}");
                    }
                }
                let stream = (!streamed.is_empty())
                    .then(|| crate::ooc::StreamSummary::new(&streamed, real_time, behind));
                runs.push(RunRecord {
                    flight: info.name.clone(),
                    method: *method,
                    from_store,
                    parameter,
                    value,
                    summary: RunSummary::new(&frames),
                    frames,
                    stream,
                });
            }
        }
    }
    if let (Some(Ok(store)), None) = (&store, &cfg.ooc_store) {
        let _ = std::fs::remove_dir_all(store.dir());
    }
    Ok(BenchReport {
        terrain: terrain.to_string(),
        grid,
        adapter: gpu.filter(|_| render_size.is_some()).map(GpuContext::describe),
        timing_notes: notes,
        leaf_cells,
        measure_viewport: [cfg.measure_viewport.0, cfg.measure_viewport.1],
        render_size: render_size.map(|(w, h)| [w, h]),
        flights: infos,
        runs,
    })
}

/// Writes into store folder `dir` the per-node tables the store-backed runs of `methods` read
/// (what `terrain bake` writes beside the blocks), from what `scene` computed in memory.
fn write_tables(
    scene: &MethodScene,
    methods: &[LodMethod],
    dir: &std::path::Path,
) -> anyhow::Result<()> {
    let uses = |m: &[LodMethod]| methods.iter().any(|x| m.contains(x));
    let pvps = [
        LodMethod::PvpsA,
        LodMethod::PvpsB,
        LodMethod::PvpsC,
        LodMethod::PvpsCPvs,
        LodMethod::PvpsCConservative,
    ];
    if uses(&pvps) {
        let leaf = scene.qt.leaf_cells();
        crate::roughness_scene::bake_from_heightmap(&scene.hm, leaf, dir, true)?;
    }
    if uses(&[LodMethod::Geomorph]) {
        crate::geomip_scene::write_into_scene(scene.geomip_scene().table(), &scene.hm, dir)?;
    }
    if uses(&[LodMethod::Dss1, LodMethod::Dss2, LodMethod::DssStrips, LodMethod::DssStripsPow2]) {
        let path = crate::dss_scene::dss_path(dir);
        std::fs::write(&path, scene.dss_errors().encode(&scene.hm))
            .with_context(|| format!("could not write {}", path.display()))?;
    }
    for (kind, mode) in [
        (LodMethod::PvpsCPvs, PvsMode::Sampled),
        (LodMethod::PvpsCConservative, PvsMode::Conservative),
    ] {
        if uses(&[kind])
            && let Some(pvs) = scene.pvs(usize::from(mode == PvsMode::Conservative))
        {
            let path = crate::pvs_scene::pvs_path(dir, mode);
            write_pvs(pvs, &path).with_context(|| format!("could not write {}", path.display()))?;
        }
    }
    Ok(())
}

/// The store of the out-of-core method: the configured one, or `hm` baked into a temporary
/// folder (see [`BenchConfig::ooc_store`]).
fn prepare_store(hm: &Heightmap, cfg: &BenchConfig) -> Result<Arc<terrain_stream::Store>, String> {
    let dir = match &cfg.ooc_store {
        Some(d) => d.clone(),
        None => {
            // One folder per call: parallel tests of one process bench grids of the same
            // width, and a shared name let one bake overwrite the store another was reading.
            static SERIAL: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
            let serial = SERIAL.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            let dir = std::env::temp_dir().join(format!(
                "terrain-bench-ooc-{}-{serial}-{}",
                std::process::id(),
                hm.width()
            ));
            crate::ooc::bake_temporary(hm, cfg.ooc_k, &dir).map_err(|e| format!("{e:#}"))?;
            dir
        }
    };
    let store = crate::ooc::open_store(&dir).map_err(|e| e.to_string())?;
    let h = store.header();
    if (h.width, h.height) != (hm.width() as u64, hm.height() as u64) {
        return Err(format!(
            "{} is {} x {} samples, the DEM {} x {}",
            dir.display(),
            h.width,
            h.height,
            hm.width(),
            hm.height()
        ));
    }
    Ok(Arc::new(store))
}

/// What the timings of a run on `gpu` mean, and which are trustworthy.
fn timing_notes(gpu: Option<&GpuContext>, rendered: bool) -> Vec<String> {
    let mut notes = vec![
        "Selection and CPU tessellation (the tessellator's CPU reference, as measured) are wall \
         times of single-threaded CPU work: trustworthy on an idle machine."
            .to_string(),
    ];
    match gpu.filter(|_| rendered) {
        None => notes.push(
            "Nothing was rendered (no GPU adapter): CPU ms = selection + CPU tessellation; no GPU times."
                .to_string(),
        ),
        Some(ctx) => {
            let f = &ctx.features;
            // `DeviceType::Cpu` without a direct wgpu dependency: lavapipe and llvmpipe.
            let software = format!("{:?}", ctx.adapter_info().device_type) == "Cpu";
            notes.push(
                "CPU ms = selection + the renderer's upload/encode/submit; frame ms = selection + \
                 the render call's wall time (it waits for the GPU)."
                    .to_string(),
            );
            if !f.timestamp_query {
                notes.push("GPU times: none (the adapter has no timestamp queries).".to_string());
            } else if !f.compute_timestamps_trustworthy {
                notes.push(
                    "GPU times: the compute (tessellation) pass's timestamps are untrustworthy on \
                     this adapter (lavapipe), so frame GPU ms is reported only for frames that \
                     reused the tessellation; the draw-pass time is reported always."
                        .to_string(),
                );
            } else {
                notes.push("GPU times: timestamp queries of both passes.".to_string());
            }
            if software {
                notes.push(
                    "The adapter is a software renderer: its 'GPU' work runs on the same CPU cores, \
                     so frame ms and GPU ms compare methods but do not predict hardware speed."
                        .to_string(),
                );
            }
        }
    }
    notes
}
