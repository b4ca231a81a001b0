//! Selection cost against grid size: the median per-frame selection time of every LOD method
//! on seeded synthetic grids of growing size, flown with the same relative camera poses, and
//! the growth from the smallest to the largest grid (issue 13: "selection cost follows the
//! view, not the grid"). No rendering, no error measurement (`terrain bench` does those); each
//! method at its default parameter.
//!
//! ```sh
//! cargo run --release -p terrain-app --example selection_scaling -- \
//!     [--sizes 1025,4097,16385] [--flight flights/pvps_884.json] [--frames 30] \
//!     [--methods uniform,pvps-a,pvps-b,pvps-c,dss-1,dss-2,geomorph] [--reps 3] \
//!     [--stores 1025=DIR,4097=DIR,32769=DIR] [--tau 2] [--ooc-refine eq7:32,cost:16] \
//!     [--poses relative|absolute] [--geomorph-px 7] [--geomorph-partial 8] [--clock wall|cpu] \
//!     [--geomorph-rows all|runs]
//! ```
//! Grids: `FractalConfig::with_size(n, n, 10.0)` (seed 1, 10 m spacing, 1500 m relief), built
//! once per size with every method's precomputation (`MethodScene::prepare`, timed apart).
//! Cameras: the flight resolved onto each grid (relative coordinates: the same fractions of the
//! extent and of the relief), `--frames` frames evenly spaced, 1280 x 720. Each frame is
//! selected `--reps` times and its fastest time kept (less noise from other processes).
//!
//! `--stores SIZE=DIR` adds the out-of-core method (`ooc`, Eq. 7 at `--tau` pixels) over a
//! store of the same synthetic terrain (`stream_bench bake SIZE 8 NAME` or `terrain bake
//! --synthetic SIZE`), warm: every level resident, `terrain_stream::select_patches` over the
//! store's `StoreTree` (the runtime's selection once every level has arrived), with the
//! runtime's clip range; one `ooc` column per `--ooc-refine RULE:CELLS[:PX[:SEG]]` (split rule `eq7`
//! or `cost`, smallest patch in cells, the cost split's pixel floor, the segment floor in cells;
//! default `eq7:32`, the default `OocConfig`). A size with a store and no in-memory grid in `--sizes` (e.g. 32769,
//! 4 GiB of f32) resolves the flight onto the store's level-4 overview, as `terrain render`
//! does.
//!
//! `--poses absolute` flies every grid with the smallest size's cameras, unchanged: the seeded
//! terrain does not depend on the grid's size and every grid starts at the same world origin,
//! so the smaller grid is the south-west corner of the larger one, each camera sees the same
//! near terrain, and the larger grid adds only what lies farther away: the case where
//! "selection follows the view, not the grid" can hold for error-driven methods at equal
//! `tau` (Eq. 7 bounds the same screen error on every grid). `--tau` also takes one value per
//! size (`1025=2.4,16385=1.4`).
//!
//! With `--stores` and `geomorph` among the methods, two more rows time geomorph from each
//! store (its `geomip.bin` over the store's patch tree, the cameras of the `ooc` rows): the
//! selection as runs (`GeomipTable::select_runs`), the runs expanded to one entry per patch
//! (`GeomipTable::select`, what the store's frame loop takes) and one patch at a time
//! (`GeomipTable::select_each`, the computation without runs, as main's `select`).
//!
//! `--geomorph-rows runs` times only the runs row (the other two are left empty).
//!
//! `--geomorph-partial W` sets geomorph's `GeomipConfig::partial_run_patches` (partly visible
//! nodes up to `W` patches wide drawn whole as runs; 0: never, the selection before it).
//!
//! Per method and size the table gives the median over frames of: selection ms, patches
//! selected (geomorph: drawn, in runs or not), nodes the traversal visited
//! (`SelectionStats::visited`; geomorph's runs: the number of runs; `-` where the method does
//! not count them), ns per selected patch, and the nominal triangles (each patch at its inner
//! factors, `2 f_u f_v`; geomorph's `2 (16 / 2^level)^2`); then the growth of the ms from the
//! smallest size to the largest.

mod common;

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use anyhow::Context;
use terrain_app::bench::{median, thread_cpu_s};
use terrain_app::methods::{LodMethod, MethodConfig, MethodScene};
use terrain_app::ooc::{OocConfig, OocScene};
use terrain_core::Heightmap;
use terrain_core::flight::{FlightConfig, FlightSpec};
use terrain_core::geometry::Camera;
use terrain_core::lod::{GeomipConfig, GeomipRuns, PatchLod};
use terrain_core::quadtree::NodeTree;
use terrain_core::synth::FractalConfig;
use terrain_stream::{Refinement, SplitRule, Store, StoreTree, select_patches};

/// One method at one size: medians of ms, patches, visited (NaN: not counted), nominal
/// triangles.
#[derive(Debug, Clone, Copy)]
struct Row {
    ms: f64,
    patches: f64,
    visited: f64,
    triangles: f64,
}

/// Triangles a selection's patches tessellate to at their inner factors (`2 f_u f_v` per
/// patch; the outer factors change a few per edge): a size figure comparable between methods.
fn nominal_triangles(sel: &terrain_core::lod::Selection) -> usize {
    sel.patches.iter().map(|p| (2.0 * p.inner[0].ceil() * p.inner[1].ceil()) as usize).sum()
}

/// Geomorph's nominal triangles: `2 (P / 2^level)^2` per patch, a run's patches at the
/// coarsest level (2 each).
fn geomorph_triangles(runs: &GeomipRuns, patch_cells: u32) -> usize {
    let n = patch_cells as usize;
    let coarse = 2 * (n >> runs.coarsest).pow(2);
    runs.patches.iter().map(|p| 2 * (n >> p.level).pow(2)).sum::<usize>()
        + coarse * runs.run_patches() as usize
}

/// What a selection's time is: wall time (default), or this thread's CPU time (`--clock cpu`:
/// on a loaded machine wall time includes waiting for a core).
#[derive(Debug, Clone, Copy, PartialEq)]
enum Clock {
    Wall,
    Cpu,
}

static CLOCK: std::sync::OnceLock<Clock> = std::sync::OnceLock::new();

fn clock() -> Clock {
    *CLOCK.get().unwrap_or(&Clock::Wall)
}

/// Times `select` on every camera (fastest of `reps` per camera) and takes the medians.
fn measure(
    cameras: &[Camera],
    reps: usize,
    mut select: impl FnMut(&Camera) -> (usize, Option<usize>, usize),
) -> Row {
    let (mut times, mut patches, mut visited) = (Vec::new(), Vec::new(), Vec::new());
    let mut triangles = Vec::new();
    for c in cameras {
        let mut best = f64::INFINITY;
        let mut counts = (0, None, 0);
        for _ in 0..reps {
            let (t, cpu) = (Instant::now(), thread_cpu_s());
            counts = select(c);
            let ms = match clock() {
                Clock::Wall => t.elapsed().as_secs_f64() * 1e3,
                Clock::Cpu => (thread_cpu_s() - cpu) * 1e3,
            };
            best = best.min(ms);
        }
        times.push(best);
        patches.push(counts.0 as f64);
        visited.push(counts.1.map_or(f64::NAN, |v| v as f64));
        triangles.push(counts.2 as f64);
    }
    let visited = if visited.iter().all(|v| v.is_nan()) {
        f64::NAN
    } else {
        median(visited.into_iter().map(|v| if v.is_nan() { 0.0 } else { v }).collect())
    };
    Row { ms: median(times), patches: median(patches), visited, triangles: median(triangles) }
}

fn frames_of(all: &[Camera], frames: usize) -> Vec<Camera> {
    let step = (all.len() / frames.max(1)).max(1);
    all.iter().step_by(step).take(frames.max(1)).cloned().collect()
}

/// The cameras flown over `ground`: the flight resolved onto it (relative poses, or the first
/// grid of an absolute run), or the first grid's cameras unchanged (`--poses absolute`: the
/// seeded terrain does not depend on the grid's size and every grid starts at the same world
/// origin, so the smaller grid is the south-west corner of the larger one).
fn poses(
    base: &mut Option<Vec<Camera>>,
    absolute: bool,
    ground: &Heightmap,
    spec: &FlightSpec,
    flight_cfg: &FlightConfig,
    frames: usize,
) -> Vec<Camera> {
    if let (true, Some(cams)) = (absolute, base.as_ref()) {
        return cams.clone();
    }
    let (resolved, _) = spec.resolve(ground, flight_cfg);
    let cams = frames_of(resolved.frames(), frames);
    if absolute {
        *base = Some(cams.clone());
    }
    cams
}

fn main() -> anyhow::Result<()> {
    let mut args = common::Args::from_env();
    let mut sizes: Vec<u64> = args
        .take_or("--sizes", "1025,4097,16385")
        .split(',')
        .filter(|s| !s.is_empty())
        .map(|s| s.parse().context("--sizes: comma-separated sample counts"))
        .collect::<anyhow::Result<_>>()?;
    let in_memory = sizes.clone();
    let stores: Vec<(u64, PathBuf)> = args
        .take_or("--stores", "")
        .split(',')
        .filter(|s| !s.is_empty())
        .map(|s| {
            let (n, dir) = s.split_once('=').context("--stores: SIZE=DIR,...")?;
            Ok((n.parse().context("--stores: SIZE")?, PathBuf::from(dir)))
        })
        .collect::<anyhow::Result<_>>()?;
    for (n, _) in &stores {
        if !sizes.contains(n) {
            sizes.push(*n);
        }
    }
    sizes.sort_unstable();
    let flight = args.take_or("--flight", "flights/pvps_884.json");
    let frames: usize = args.take_or("--frames", "30").parse().context("--frames")?;
    let reps: usize = args.take_or("--reps", "3").parse::<usize>().context("--reps")?.max(1);
    let taus = args.take_or("--tau", "2");
    let _ = CLOCK.set(match args.take_or("--clock", "wall").as_str() {
        "wall" => Clock::Wall,
        "cpu" => Clock::Cpu,
        other => anyhow::bail!("--clock {other}: wall or cpu"),
    });
    // Geomorph's pixel threshold (its `terrain bench --values`; p99 1 px is near 7 on the big
    // stores), default the method's.
    let geomorph_px: f64 = args
        .take_or("--geomorph-px", &MethodConfig::default().geomip.pixel_threshold.to_string())
        .parse()
        .context("--geomorph-px")?;
    // Geomorph's partly visible nodes drawn whole as runs up to this many patches wide
    // (`GeomipConfig::partial_run_patches`; 0: never, main's selection before).
    let partial: u32 = args
        .take_or(
            "--geomorph-partial",
            &MethodConfig::default().geomip.partial_run_patches.to_string(),
        )
        .parse()
        .context("--geomorph-partial")?;
    // `runs`: geomorph's store rows time only `select_runs` (the expanded and per-patch rows
    // are left empty: quicker, and a profile of the runs alone).
    let geomorph_rows = args.take_or("--geomorph-rows", "all");
    anyhow::ensure!(
        matches!(geomorph_rows.as_str(), "all" | "runs"),
        "--geomorph-rows {geomorph_rows}: all or runs"
    );
    let method_config = || {
        let mut c = MethodConfig::default();
        c.geomip.pixel_threshold = geomorph_px;
        c.geomip.partial_run_patches = partial;
        c
    };
    let tau_of = |n: u64| -> anyhow::Result<f64> {
        if !taus.contains('=') {
            return taus.parse().context("--tau: pixels, or SIZE=PX,...");
        }
        taus.split(',')
            .filter_map(|t| t.split_once('='))
            .find(|(m, _)| m.parse() == Ok(n))
            .with_context(|| format!("--tau {taus}: no value for size {n}"))?
            .1
            .parse()
            .context("--tau: SIZE=PX")
    };
    let absolute = match args.take_or("--poses", "relative").as_str() {
        "relative" => false,
        "absolute" => true,
        other => anyhow::bail!("--poses {other}: relative or absolute"),
    };
    let mut methods: Vec<LodMethod> = args
        .take_or("--methods", "uniform,pvps-a,pvps-b,pvps-c,dss-1,dss-2,geomorph")
        .split(',')
        .filter(|s| !s.is_empty())
        .map(|m| {
            LodMethod::ALL
                .iter()
                .copied()
                .find(|x| x.name() == m)
                .with_context(|| format!("unknown method {m}"))
        })
        .collect::<anyhow::Result<_>>()?;
    methods.retain(|&m| m != LodMethod::OutOfCore);
    let mut names: Vec<String> = methods.iter().map(|m| m.name().to_string()).collect();
    let refines: Vec<(String, Refinement)> = args
        .take_or("--ooc-refine", "eq7:32")
        .split(',')
        .filter(|s| !s.is_empty())
        .map(|r| {
            // RULE:CELLS[:PX[:SEG]] (PX: the cost split's screen-size floor, SEG: the segment
            // floor in cells, `Refinement::max_segment_cells`; default the library's).
            let mut parts = r.split(':');
            let (rule, cells) = (parts.next().unwrap_or(""), parts.next());
            let cells =
                cells.with_context(|| format!("--ooc-refine {r}: RULE:CELLS[:PX[:SEG]]"))?;
            let cost_split_px = match parts.next() {
                Some(px) => px.parse().with_context(|| format!("--ooc-refine {r}"))?,
                None => Refinement::default().cost_split_px,
            };
            let max_segment_cells = match parts.next() {
                Some(seg) => seg.parse().with_context(|| format!("--ooc-refine {r}"))?,
                None => Refinement::default().max_segment_cells,
            };
            let split = match rule {
                "eq7" => SplitRule::Eq7,
                "cost" => SplitRule::Cost,
                _ => anyhow::bail!("--ooc-refine: unknown split rule {rule} (eq7 or cost)"),
            };
            let patch_cells = cells.parse().with_context(|| format!("--ooc-refine {r}"))?;
            Ok((
                r.to_string(),
                Refinement {
                    patch_cells,
                    split,
                    cost_split_px,
                    max_segment_cells,
                    ..Refinement::default()
                },
            ))
        })
        .collect::<anyhow::Result<_>>()?;
    if !stores.is_empty() {
        names.extend(refines.iter().map(|(r, _)| format!("ooc {r} (tau {taus})")));
    }
    // Geomorph from a store: its table (`geomip.bin`) over the store's patch tree, as runs and
    // one patch at a time (the computation without runs, as main's `select`).
    let geo_store = !stores.is_empty() && methods.contains(&LodMethod::Geomorph);
    if geo_store {
        names.push("geomorph runs (store)".into());
        names.push("geomorph runs expanded (store)".into());
        names.push("geomorph per patch (store)".into());
    }
    let spec = FlightSpec::load(&flight).with_context(|| format!("flight {flight}"))?;
    let flight_cfg = FlightConfig::default();

    // Per method: per size, the row (None: not run at that size).
    let mut table: Vec<Vec<Option<Row>>> = vec![Vec::new(); names.len()];
    // `--poses absolute`: the smallest size's cameras and the ground they were placed over.
    let mut base: Option<Vec<Camera>> = None;
    for &n in &sizes {
        let store = stores.iter().find(|(m, _)| *m == n).map(|(_, d)| d);
        let mut cameras = None;
        if in_memory.contains(&n) {
            let t = Instant::now();
            let hm =
                FractalConfig::with_size(n, n, 10.0).to_heightmap().map_err(anyhow::Error::msg)?;
            let gen_s = t.elapsed().as_secs_f64();
            let cams = poses(&mut base, absolute, &hm, &spec, &flight_cfg, frames);
            let scene = MethodScene::new(hm, method_config());
            let t = Instant::now();
            scene.prepare(&methods);
            eprintln!(
                "{n}^2: grid {gen_s:.1} s, precomputation {:.1} s, {} cameras",
                t.elapsed().as_secs_f64(),
                cams.len()
            );
            for (k, &m) in methods.iter().enumerate() {
                let mut single = Vec::new();
                let row = measure(&cams, reps, |c| {
                    if m == LodMethod::Geomorph {
                        // Its own selection (levels, tween factors): what the morph draws, as
                        // runs of coarsest patches and the others one by one.
                        let runs = scene.select_geomorph_runs(c, scene.config.geomip.morph);
                        single.push(runs.patches.len() as f64);
                        let n = scene.geomorph_patch_cells();
                        (
                            runs.drawn_patches() as usize,
                            Some(runs.runs.len()),
                            geomorph_triangles(&runs, n),
                        )
                    } else {
                        let sel = scene.select(m, c);
                        // `uniform` does not count its visits (0).
                        let visited = sel.stats.visited;
                        (
                            sel.patches.len(),
                            (visited > 0).then_some(visited),
                            nominal_triangles(&sel),
                        )
                    }
                });
                eprintln!(
                    "  {:<9} {:>9.3} ms {:>8.0} patches {:>8.0} visited {:>9.0} triangles",
                    m.name(),
                    row.ms,
                    row.patches,
                    row.visited,
                    row.triangles
                );
                if !single.is_empty() {
                    eprintln!("  geomorph: median {:.0} patches not in runs", median(single));
                }
                table[k].push(Some(row));
            }
            cameras = Some(cams);
        } else {
            for column in table.iter_mut().take(methods.len()) {
                column.push(None);
            }
        }
        if let Some(dir) = store {
            let scene = OocScene::open(dir, OocConfig::default())
                .with_context(|| format!("store {}", dir.display()))?;
            let cams = match cameras {
                Some(c) => c,
                None => {
                    let overview = scene.overview(4).context("the store's overview")?;
                    poses(&mut base, absolute, &overview, &spec, &flight_cfg, frames)
                }
            };
            let cams: Vec<Camera> = cams
                .iter()
                .map(|c| {
                    let (near, far) = scene.clip_range(c.position);
                    c.with_clip(near, far)
                })
                .collect();
            let store: Arc<Store> = scene.store().clone();
            let k = store.header().k;
            let tau = tau_of(n)?;
            for (r, (name, refine)) in refines.iter().enumerate() {
                let tree = StoreTree::with_refinement(store.clone(), *refine);
                let row = measure(&cams, reps, |c| {
                    let sel = select_patches(&tree, c, tau, |_| Some(k));
                    (sel.patches.len(), Some(sel.stats.visited), nominal_triangles(&sel))
                });
                eprintln!(
                    "  ooc {name:<9} {:>9.3} ms {:>8.0} patches {:>8.0} visited {:>9.0} triangles (store {})",
                    row.ms,
                    row.patches,
                    row.visited,
                    row.triangles,
                    dir.display()
                );
                table[methods.len() + r].push(Some(row));
            }
            if geo_store {
                let cells = method_config().leaf_cells.clamp(2, 64).next_power_of_two();
                let tree = StoreTree::new(store.clone(), cells);
                let t = Instant::now();
                let geomip = terrain_app::geomip_scene::read_for_store(tree.store(), tree.shape())?
                    .exaggerated(store.header().vertical_scale);
                eprintln!("  geomorph table read in {:.1} s", t.elapsed().as_secs_f64());
                let cfg =
                    GeomipConfig { patch_cells: geomip.patch_cells(), ..method_config().geomip };
                let col = methods.len() + refines.len();
                let (mut single, mut coarse, mut flat) = (Vec::new(), Vec::new(), Vec::new());
                let runs = measure(&cams, reps, |c| {
                    let r = geomip.select_runs(&tree, c, &cfg);
                    single.push(r.patches.len() as f64);
                    let l = r.coarsest;
                    coarse
                        .push(r.patches.iter().filter(|p| p.level == l && p.tween == 0.0).count()
                            as f64);
                    // Finer single patches drawn at their level exactly (tween 0, every edge
                    // at it): what runs of a finer level could hold.
                    let exact = |p: &&PatchLod| {
                        p.level < l
                            && p.tween == 0.0
                            && p.edge_level == [p.level; 4]
                            && p.edge_tween == [0.0; 4]
                    };
                    flat.push(r.patches.iter().filter(exact).count() as f64);
                    let tris = geomorph_triangles(&r, cfg.patch_cells);
                    (r.drawn_patches() as usize, Some(r.runs.len()), tris)
                });
                let others = if geomorph_rows == "runs" { &cams[..0] } else { &cams[..] };
                let expanded = measure(others, reps, |c| {
                    let s = geomip.select(&tree, c, &cfg);
                    let n = cfg.patch_cells as usize;
                    let tris = s.patches.iter().map(|p| 2 * (n >> p.level).pow(2)).sum();
                    (s.patches.len(), None, tris)
                });
                let each = measure(others, reps, |c| {
                    let s = geomip.select_each(&tree, c, &cfg);
                    let n = cfg.patch_cells as usize;
                    let tris = s.patches.iter().map(|p| 2 * (n >> p.level).pow(2)).sum();
                    (s.patches.len(), None, tris)
                });
                eprintln!(
                    "  geomorph runs: median {:.0} patches one by one (not in runs), {:.0} of them \
                     at the coarsest level with tween 0, {:.0} at a finer level with tween 0 and \
                     every edge at it",
                    median(single),
                    median(coarse),
                    median(flat)
                );
                for (k, row) in [runs, expanded, each].into_iter().enumerate() {
                    eprintln!(
                        "  {:<26} {:>9.3} ms {:>8.0} patches {:>8.0} runs {:>9.0} triangles",
                        names[col + k],
                        row.ms,
                        row.patches,
                        row.visited,
                        row.triangles
                    );
                    table[col + k].push(Some(row));
                }
            }
        } else if !stores.is_empty() {
            for column in table.iter_mut().skip(methods.len()) {
                column.push(None);
            }
        }
    }
    println!(
        "\nmedian per frame: selection ms / patches / visited nodes / ns per patch / nominal triangles; flight \
         {flight}, {frames} frames, 1280x720"
    );
    print!("| method |");
    for n in &sizes {
        print!(" {n}^2 |");
    }
    println!(" growth of ms, largest / smallest size |");
    println!("|---|{}---|", "---|".repeat(sizes.len()));
    for (k, name) in names.iter().enumerate() {
        print!("| {name} |");
        for row in &table[k] {
            match row {
                Some(r) => {
                    let visited = if r.visited.is_nan() {
                        "-".to_string()
                    } else {
                        format!("{:.0}", r.visited)
                    };
                    print!(
                        " {:.3} / {:.0} / {visited} / {:.0} / {:.0} |",
                        r.ms,
                        r.patches,
                        r.ms * 1e6 / r.patches.max(1.0),
                        r.triangles
                    );
                }
                None => print!(" |"),
            }
        }
        let run: Vec<&Row> = table[k].iter().flatten().collect();
        match (run.first(), run.last()) {
            (Some(a), Some(b)) if run.len() > 1 => println!(" {:.1}x |", b.ms / a.ms.max(1e-9)),
            _ => println!(" |"),
        }
    }
    Ok(())
}
