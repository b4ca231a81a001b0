//! The whole per-frame CPU cost of a LOD method drawn from a baked store (issue 13): the
//! store method's `frame` (selection, the streamer's demand and update, page assignment, the
//! drawn-block filter, the frame's draw lists) timed per frame with this thread's CPU clock,
//! no rendering and no measurement, split into the selection (the frame's `selection_ms`), the
//! streaming step (`stream_ms`: the demand, `Streamer::update`) and the rest.
//!
//! ```sh
//! cargo build --release -p terrain-app --example store_frame
//! target/release/examples/store_frame STORE [--method geomorph] [--px 7] \
//!     [--flight flights/pvps_884.json] [--frames 10] [--paced] [--error-px 1]
//! ```
//! `--px` sets geomorph's and `tin`'s pixel thresholds directly (the other methods keep their
//! defaults: `ooc`'s `tau` 2, the PVPS paper's constants); `--error-px` maps a p99 target onto
//! every method's own parameter as `terrain bench --error-px` does.
//! Cameras: the flight resolved onto the store's overview (as `selection_scaling`'s store
//! rows), `--frames` frames evenly spaced, 1280 x 720. The first frame waits until its levels
//! are resident (not timed); the others draw what is resident (real time), each timed. The
//! figures are medians over the timed frames (each column its own median). `--paced` makes
//! each frame last at least 1/30 s of wall time (the workers' time between frames in a
//! paced flight; with `--frames` at the flight's frame count, consecutive frames); a frame
//! that takes longer holds the flight back and gives the workers its time, so the summary
//! also counts the frames after the first that ran over the period, and by how much in all.

mod common;

use std::path::PathBuf;

use anyhow::Context;
use terrain_app::bench::{median, thread_cpu_s};
use terrain_app::method::registry::{ErrorView, params_for_error_px};
use terrain_app::method::{Draw, OocWait, store_method};
use terrain_app::methods::{LodMethod, MethodConfig};
use terrain_app::ooc::{MorphDraw, OocConfig, OocScene, morph_demand, morph_on_pages};
use terrain_core::flight::{FlightConfig, FlightSpec};
use terrain_core::lod::GeomipConfig;
use terrain_core::quadtree::NodeTree;
use terrain_stream::StoreTree;

fn main() -> anyhow::Result<()> {
    let mut args = common::Args::from_env();
    let method = args.take("--method").unwrap_or_else(|| "geomorph".into());
    let px: Option<f64> = args.take("--px").map(|v| v.parse()).transpose().context("--px")?;
    let flight = args.take("--flight").unwrap_or_else(|| "flights/pvps_884.json".into());
    let frames: usize = args.take("--frames").map_or(Ok(10), |v| v.parse()).context("--frames")?;
    // Each frame lasts at least one period of the flight's frame rate in wall time (the
    // workers' time between frames, as in a paced render), with `--paced`.
    let paced = args.flag("--paced");
    let dir = PathBuf::from(args.rest().first().context("usage: store_frame STORE [options]")?);
    let kind = <LodMethod as clap::ValueEnum>::from_str(&method, true)
        .map_err(|e| anyhow::anyhow!("--method {method}: {e}"))?;
    // The one quality knob (`--error-px` of `terrain bench`): every method's own parameter
    // for a p99 target, `ooc`'s `tau` from its store's calibration (or the shared one).
    let error_px: Option<f64> =
        args.take("--error-px").map(|v| v.parse()).transpose().context("--error-px")?;
    let mut config = MethodConfig::default();
    if let Some(px) = px {
        config.geomip.pixel_threshold = px;
        config.tin.tau_px = px;
    }
    let mut ooc = OocConfig::default();
    if let Some(px) = error_px {
        // As `terrain render` and `fly` do: the store's calibration when it has one.
        ooc.calibration = terrain_app::ooc_calibration::of_store(&dir)?;
        params_for_error_px(kind, px, ErrorView::REFERENCE).apply(&mut config);
        // The scene's `tau` whatever the method (it also sets the streamer's Eq. 7 levels).
        ooc.tau = ooc.tau_for_error_px(px).0;
        eprintln!("--error-px {px}: ooc tau {:.4}, pvps C3 {:.3}", ooc.tau, config.pvps.c3);
    }
    let scene = OocScene::open(&dir, ooc).with_context(|| format!("store {}", dir.display()))?;
    let overview = scene.overview(4).context("the store's overview")?;
    let spec = FlightSpec::load(&flight).with_context(|| format!("flight {flight}"))?;
    let (resolved, _) = spec.resolve(&overview, &FlightConfig::default());
    let all = resolved.frames();
    let step = (all.len() / frames.max(1)).max(1);
    let cameras: Vec<_> = all
        .iter()
        .step_by(step)
        .take(frames.max(1))
        .map(|c| {
            let (near, far) = scene.clip_range(c.position);
            c.with_clip(near, far)
        })
        .collect();
    // Geomorph's selection alone, timed on this thread's CPU clock over the store's patch tree
    // (node boxes only), the frame's own `selection_ms` being wall time.
    let geo = if kind == LodMethod::Geomorph {
        let store = scene.store().clone();
        let cells = config.leaf_cells.clamp(2, 64).next_power_of_two();
        let tree = StoreTree::new(store.clone(), cells);
        // The method's own page cache, from the scene's budget.
        let budget = scene.config().budget_bytes;
        let table =
            terrain_app::geomip_scene::read_for_store_within(tree.store(), tree.shape(), budget)?
                .exaggerated(store.header().vertical_scale);
        let cfg = GeomipConfig { patch_cells: table.patch_cells(), ..config.geomip };
        Some((tree, table, cfg))
    } else {
        None
    };
    // Opening the method (its tables: for geomorph `geomip.bin`, by pages or whole).
    let (t, wall) = (thread_cpu_s(), std::time::Instant::now());
    let store = scene.store().clone();
    let mut m = store_method(kind, scene, &config, OocWait::FirstFrame, None)?;
    eprintln!(
        "method opened: {:.3} s CPU, {:.3} s wall",
        thread_cpu_s() - t,
        wall.elapsed().as_secs_f64()
    );
    let (mut total, mut select, mut stream, mut rest) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut on_runs = Vec::new();
    // Geomorph: the frame's own selection (wall), which builds the pyramid tiles the view
    // enters; the timed second selection at the same camera finds them built.
    let mut own = Vec::new();
    let mut late_frames = 0;
    let period = std::time::Duration::from_secs_f64(1.0 / 30.0);
    // Paced frames after the first over the period, and their time over it.
    let (mut over_frames, mut over) = (0, std::time::Duration::ZERO);
    for (k, c) in cameras.iter().enumerate() {
        let started = std::time::Instant::now();
        let t = thread_cpu_s();
        let f = m.frame(c);
        let ms = (thread_cpu_s() - t) * 1e3;
        let s = f.stats.stream.as_ref().map_or(0.0, |s| s.stream_ms);
        let (sel, runs_ms) = match &geo {
            Some((tree, table, cfg)) => {
                let t = thread_cpu_s();
                let runs = table.select_runs(tree, c, cfg);
                let sel = (thread_cpu_s() - t) * 1e3;
                // The frame's run-based demand and drawn-block filter, timed apart on the same
                // runs and the frame's drawn blocks.
                let drawn = match &f.draw {
                    Draw::PagedMorph(p, _) => p.drawn.iter().copied().collect(),
                    _ => terrain_core::hash::IdMap::default(),
                };
                let t = thread_cpu_s();
                let morph = MorphDraw { runs, patch_cells: cfg.patch_cells };
                std::hint::black_box(morph_demand(tree, &morph).len());
                std::hint::black_box(morph_on_pages(tree, morph.runs, &drawn).runs.len());
                (sel, (thread_cpu_s() - t) * 1e3)
            }
            None => (f.stats.selection_ms, f64::NAN),
        };
        // Geomorph's compact selection only: its demand and drawn-block filter timed apart.
        let mut more_part = match geo.is_some() {
            true => format!(", demand + filter from runs {runs_ms:.2} ms CPU"),
            false => String::new(),
        };
        // A waiting frame's wait (the first of a real-time run): for blocks and tiles.
        if let Some(w) = f.stats.stream.as_ref().map(|s| s.wait_ms).filter(|&w| w > 0.0) {
            more_part += &format!(", waited {w:.1} ms");
        }
        eprintln!(
            "frame {k}: {ms:.2} ms CPU, selection {sel:.2} ms CPU ({:.2} wall), stream {s:.2} \
             ms{more_part}, {} patches, needed {:.0} MiB \
             (late {:.3} MiB in {} blocks, {} tiles late), resident {:.0} MiB, queue {} \
             ({:.1} MiB), prefetched {:.2} MiB, cancelled {}, evictions {}{}",
            f.stats.selection_ms,
            f.stats.patches,
            f.stats.stream.as_ref().map_or(0.0, |s| s.needed_mib),
            f.stats.stream.as_ref().map_or(0.0, |s| s.late_mib),
            f.stats.stream.as_ref().map_or(0, |s| s.late_blocks),
            f.stats.stream.as_ref().map_or(0, |s| s.late_tiles),
            f.stats.stream.as_ref().map_or(0.0, |s| s.resident_mib),
            f.stats.stream.as_ref().map_or(0, |s| s.queue_depth),
            f.stats.stream.as_ref().map_or(0.0, |s| s.queued_mib),
            f.stats.stream.as_ref().map_or(0.0, |s| s.prefetched_mib),
            f.stats.stream.as_ref().map_or(0, |s| s.cancelled),
            f.stats.stream.as_ref().map_or(0, |s| s.evictions),
            if f.stats.stream.as_ref().is_some_and(|s| s.demand_on_lattice) {
                " (demand on lattices)"
            } else {
                ""
            }
        );
        if k > 0 && f.stats.stream.as_ref().is_some_and(|s| !s.at_needed_level) {
            late_frames += 1;
        }
        if paced {
            let took = started.elapsed();
            if k > 0 && took > period {
                over_frames += 1;
                over += took - period;
            }
            std::thread::sleep(period.saturating_sub(took));
        }
        if k > 0 {
            total.push(ms);
            select.push(sel);
            on_runs.push(runs_ms);
            own.push(f.stats.selection_ms);
            stream.push(s);
            rest.push(ms - sel - s);
        }
    }
    if let Some(p) = geo.as_ref().and_then(|g| g.1.paging_stats()) {
        eprintln!(
            "geomip.bin read by pages: {:.2} MB read, {} pages, {} pyramid tiles, {:.2} MB cached",
            p.bytes_read as f64 / 1e6,
            p.pages_read,
            p.tiles_built,
            p.cached_bytes as f64 / 1e6
        );
    }
    let (t, s, st, r) = (median(total), median(select), median(stream), median(rest));
    println!(
        "{} {method}: frame {t:.2} ms CPU (median of {}), selection {s:.2}, stream {st:.2}, \
         rest {:.2}{}; frames after the first not at their needed level: {late_frames}{}",
        dir.display(),
        cameras.len().saturating_sub(1),
        r,
        match geo.is_some() {
            true => format!(
                "; demand + filter from runs {:.2} ms CPU; the frame's own selection {:.2} ms \
                 wall (with the pyramid tiles it builds)",
                median(on_runs),
                median(own)
            ),
            false => String::new(),
        },
        match paced {
            true => format!(
                "; over the 1/30 s period: {over_frames} ({:.2} s over)",
                over.as_secs_f64()
            ),
            false => String::new(),
        }
    );
    if let (Some(decoded), Some((budget, whole))) =
        (store.index_pages_decoded(), store.index_cache_bytes())
    {
        println!(
            "index pages decoded: {decoded} (cache {:.0} MiB of the whole index's {:.0})",
            budget as f64 / f64::from(1 << 20),
            whole as f64 / f64::from(1 << 20)
        );
    }
    Ok(())
}
