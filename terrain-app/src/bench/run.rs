//! Running the benchmark: [`run_bench`] over flights, methods and sweep values (the
//! out-of-core method through its store and streaming runtime), progress, timing notes.

use std::time::Instant;

use glam::dvec2;
use terrain_core::Heightmap;
use terrain_core::flight::{FlightConfig, FlightSpec, FlightWarning};
use terrain_core::measure::Measurer;
use terrain_gpu::geomorph::{GeomorphConfig, GeomorphRenderer};
use terrain_gpu::{GpuContext, RenderConfig, RenderOptions, TerrainRenderer};

use super::config::{BenchConfig, apply_parameter, frame_indices, pick_evenly, sweep_values};
use super::frame::{FrameRunner, ms};
use super::record::{BenchReport, FlightInfo, FrameRecord, RunRecord, RunSummary, rss_bytes};
use crate::methods::{LodMethod, MethodScene, drawn_surface_of};
use crate::ooc::{OocConfig, OocScene};

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

/// A plain-text progress bar on stderr, rewritten in place.
pub fn print_progress(p: &BenchProgress) {
    let width = 30;
    let filled = (p.done * width).checked_div(p.total).unwrap_or(width);
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
    let mut renderer = match (gpu, render_size) {
        (Some(ctx), Some((width, height))) => Some(TerrainRenderer::new(
            ctx,
            &hm,
            &RenderConfig { width, height, background: [150, 185, 225, 255], ..Default::default() },
        )?),
        _ => None,
    };
    let mut geomorph_renderer = match (gpu, render_size) {
        (Some(ctx), Some((width, height))) if cfg.methods.contains(&LodMethod::Geomorph) => {
            Some(GeomorphRenderer::new(
                ctx,
                &hm,
                &GeomorphConfig {
                    width,
                    height,
                    patch_cells: cfg.method.leaf_cells.clamp(2, 64),
                    background: [150, 185, 225, 255],
                    ..Default::default()
                },
            )?)
        }
        _ => None,
    };
    let mut notes = timing_notes(gpu, renderer.is_some());
    notes.push(format!(
        "Pixel errors and DSS's rho_thr refer to a {}x{} view; frames per flight: {}.",
        cfg.measure_viewport.0,
        cfg.measure_viewport.1,
        if cfg.max_frames == 0 { "all".to_string() } else { format!("at most {}", cfg.max_frames) }
    ));

    if cfg.methods.contains(&LodMethod::Entropy) {
        notes.push(
            "entropy: a triangle mesh, measured on the CPU and drawn as the renderer's extra \
             triangles (uploaded every frame); its selection time is the Eq. 5 cut, its \
             tessellation time the crack elimination and tile triangulation."
                .to_string(),
        );
    }
    let mut scene = MethodScene::new(hm, cfg.method.clone());
    if let Some(dir) = &cfg.scene {
        for warning in crate::scene_files::load(&scene, dir, &cfg.methods) {
            eprintln!("warning: {warning}");
            notes.push(warning);
        }
    }
    scene.prepare(&cfg.methods);
    let leaf_cells = scene.config.leaf_cells;
    let sweeps: Vec<(LodMethod, &'static str, Vec<f64>)> = cfg
        .methods
        .iter()
        .map(|&m| {
            let (name, all) = sweep_values(m, leaf_cells);
            (m, name, pick_evenly(&all, cfg.sweep_points))
        })
        .collect();
    let per_flight: usize = sweeps.iter().map(|s| s.2.len()).sum();
    let total: usize = infos.iter().map(|i| i.frames.len() * per_flight).sum();
    let mut done = 0;
    let mut runs = Vec::new();
    let mut ooc_store: Option<Result<std::sync::Arc<terrain_stream::Store>, String>> = None;
    for ((flight, _), info) in resolved.iter().zip(&infos) {
        for (method, parameter, values) in &sweeps {
            if *method == LodMethod::OutOfCore {
                let store = ooc_store.get_or_insert_with(|| prepare_store(&scene.hm, cfg));
                let store = match store {
                    Ok(s) => s.clone(),
                    Err(e) => anyhow::bail!("the out-of-core method's store: {e}"),
                };
                for &value in values {
                    let label = format!("{} ooc tau={value}", info.name);
                    let config = OocConfig { tau: value, ..cfg.ooc };
                    let (frames, stream) = run_ooc(
                        &scene,
                        &store,
                        config,
                        cfg,
                        gpu,
                        render_size,
                        flight,
                        &info.frames,
                        &mut |_| {
                            done += 1;
                            progress(&BenchProgress { done, total, label: label.clone() });
                        },
                    )?;
                    runs.push(RunRecord {
                        flight: info.name.clone(),
                        method: *method,
                        parameter,
                        value,
                        summary: RunSummary::new(&frames),
                        frames,
                        stream: Some(stream),
                    });
                }
                continue;
            }
            for &value in values {
                let mut config = cfg.method.clone();
                config.leaf_cells = leaf_cells;
                config.pvps.leaf_cells = leaf_cells;
                config.dss.leaf_cells = leaf_cells;
                apply_parameter(&mut config, *method, value);
                scene.config = config;
                let label = format!("{} {} {parameter}={value}", info.name, method.name());
                let mut runner = FrameRunner::new(&scene, *method, cfg.measure, renderer.as_mut())
                    .with_geomorph_renderer(geomorph_renderer.as_mut());
                let mut frames = Vec::with_capacity(info.frames.len());
                for &k in &info.frames {
                    let cams = flight.frames();
                    frames.push(runner.frame_after(
                        k,
                        &cams[k],
                        k.checked_sub(1).map(|p| &cams[p]),
                    )?);
                    done += 1;
                    progress(&BenchProgress { done, total, label: label.clone() });
                }
                runs.push(RunRecord {
                    flight: info.name.clone(),
                    method: *method,
                    parameter,
                    value,
                    summary: RunSummary::new(&frames),
                    frames,
                    stream: None,
                });
            }
        }
    }
    if let (Some(Ok(store)), None) = (&ooc_store, &cfg.ooc_store) {
        let _ = std::fs::remove_dir_all(store.dir());
    }
    if ooc_store.is_some() {
        notes.push(
            if cfg.ooc_wait {
                "ooc (--wait): blocks come from a store through the streamer; every sampled frame \
                 waits for the levels it needs (warm), so its error is the selection's and the \
                 stream columns show what was loaded on the frame thread and what the workers \
                 prefetched. Sampled frames are further apart than the flight's frame rate, so \
                 Eq. 8's speed is overestimated."
            } else {
                "ooc (real time): the flight is played at its own frame rate, every frame, paced in \
                 wall time (no rendering between measured frames); no frame after the first waits \
                 for I/O, blocks are drawn at their finest resident level, and late data (needed, \
                 not resident when drawn) is counted. The sampled frames are measured and \
                 rendered while the flight's clock stops, which gives the workers extra time \
                 before the next frames; the streaming summary covers every played frame."
            }
            .to_string(),
        );
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

/// The store of the out-of-core method: the configured one, or `hm` baked into a temporary
/// folder (see [`BenchConfig::ooc_store`]).
fn prepare_store(
    hm: &Heightmap,
    cfg: &BenchConfig,
) -> Result<std::sync::Arc<terrain_stream::Store>, String> {
    use terrain_stream::{BakeConfig, BakeProgress, HeightEncoding, Store, bake};
    let dir = match &cfg.ooc_store {
        Some(d) => d.clone(),
        None => {
            let dir = std::env::temp_dir().join(format!(
                "terrain-bench-ooc-{}-{}",
                std::process::id(),
                hm.width()
            ));
            // Lossless where the heights lie on a 0.1 m lattice (scaled grey images, integer
            // DEMs), else the store's default 1 cm bound.
            let lattice = hm.data().iter().all(|&h| ((h * 10.0).round() - h * 10.0).abs() < 1e-3);
            let encoding = if lattice {
                HeightEncoding::Quantized { step_m: 0.1, offset_m: 0.0 }
            } else {
                HeightEncoding::default()
            };
            let config =
                BakeConfig { k: cfg.ooc_k, encoding, overwrite: true, ..Default::default() };
            bake(hm, &dir, &config, &mut |_: &BakeProgress| std::ops::ControlFlow::Continue(()))
                .map_err(|e| e.to_string())?;
            dir
        }
    };
    let store = Store::open(&dir).map_err(|e| e.to_string())?;
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
    Ok(std::sync::Arc::new(store))
}

/// One out-of-core run (one tau) over one flight: a fresh runtime, real time (every frame
/// played at the flight's rate, see [`BenchConfig::ooc_wait`]) or warm sampled frames, the
/// drawn surface rebuilt from the pages' heights (the CPU reference of the paged
/// renderer) and measured against the full DEM, the paged render when a GPU is given.
#[allow(clippy::too_many_arguments)]
fn run_ooc(
    scene: &MethodScene,
    store: &std::sync::Arc<terrain_stream::Store>,
    config: OocConfig,
    cfg: &BenchConfig,
    gpu: Option<&GpuContext>,
    render_size: Option<(u32, u32)>,
    flight: &terrain_core::flight::Flight,
    indices: &[usize],
    tick: &mut dyn FnMut(usize),
) -> anyhow::Result<(Vec<FrameRecord>, crate::ooc::StreamSummary)> {
    let mut ooc = OocScene::new(store.clone(), config).with_mirror();
    if ooc.root_cells() != scene.qt.root_cells() {
        anyhow::bail!(
            "the store's blocks ({} cells) do not tile the DEM's quadtree (root {} cells): bake with a smaller k",
            store.header().block_cells(),
            scene.qt.root_cells()
        );
    }
    let mut renderer = match (gpu, render_size) {
        (Some(ctx), Some((width, height))) => Some(ooc.renderer(
            ctx,
            &RenderConfig { width, height, background: [150, 185, 225, 255], ..Default::default() },
        )?),
        _ => None,
    };
    let mut measurer = Measurer::new(&scene.hm, &scene.qt, cfg.measure);
    let mut frames = Vec::with_capacity(indices.len());
    // Warm: the sampled frames only, each waiting. Real time: every frame at the flight's
    // rate; the clock restarts after each measured frame.
    let played: Vec<usize> =
        if cfg.ooc_wait { indices.to_vec() } else { (0..flight.frames().len()).collect() };
    let measured: std::collections::BTreeSet<usize> = indices.iter().copied().collect();
    let period = std::time::Duration::from_secs_f64(1.0 / flight.fps.max(1e-3));
    let (mut clock, mut since) = (Instant::now(), 0u32);
    let (mut streamed, mut behind) = (Vec::with_capacity(played.len()), 0);
    for k in played {
        let camera = &flight.frames()[k];
        if !cfg.ooc_wait {
            match (clock + period * since).checked_duration_since(Instant::now()) {
                Some(w) => std::thread::sleep(w),
                None => behind += usize::from(since > 0),
            }
            since += 1;
        }
        // The first frame waits until warm (a session's first image), as `terrain render`'s.
        let f = ooc.frame(camera, cfg.ooc_wait || streamed.is_empty());
        streamed.push(f.stream.clone());
        if !measured.contains(&k) {
            if let Some(r) = renderer.as_mut() {
                OocScene::apply(r, &f)?;
            }
            continue;
        }
        let selection_ms = f.selection.stats.cpu_time.as_secs_f64() * 1e3;
        let t = Instant::now();
        let drawn = ooc.mirror().expect("mirrored").to_heightmap(&scene.hm);
        let (mesh, triangles) = drawn_surface_of(&drawn, &scene.qt, &f.selection);
        let cpu_tess_ms = ms(t);
        drop(drawn);
        let t = Instant::now();
        let errors = measurer.measure(camera, &f.selection, &mesh);
        let measure_ms = ms(t);
        drop(mesh);
        let mut record = FrameRecord {
            stream: Some(f.stream.clone()),
            ..FrameRecord::measured(
                k,
                f.selection.patches.len(),
                triangles,
                [selection_ms, cpu_tess_ms, measure_ms],
                errors,
            )
        };
        if let Some(r) = renderer.as_mut() {
            OocScene::apply(r, &f)?;
            let t = Instant::now();
            let s = r.render(camera, &f.patches, &RenderOptions::default())?;
            let render_ms = ms(t);
            let pages: u64 = f.updates.iter().filter(|u| u.fill.is_some()).count() as u64;
            record.encode_ms = Some(s.cpu_ms);
            record.render_ms = Some(render_ms);
            record.gpu_ms = s.gpu_ms;
            record.gpu_draw_ms = s.gpu_draw_ms;
            record.gpu_tessellated = Some(s.tessellated);
            record.upload_bytes = Some(128 + pages * ooc.layout().page_len() as u64 * 4);
            record.cpu_ms = selection_ms + s.cpu_ms;
            record.frame_ms = selection_ms + render_ms;
        }
        record.rss_bytes = rss_bytes();
        frames.push(record);
        tick(k);
        (clock, since) = (Instant::now(), 0);
    }
    let summary = crate::ooc::StreamSummary::new(&streamed, !cfg.ooc_wait, behind);
    Ok((frames, summary))
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
