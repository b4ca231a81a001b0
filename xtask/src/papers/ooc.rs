//! The out-of-core paper (Qiu 2013): Table 1 (storage before and after, per level), Table 2
//! (triangles, frame rate and peak memory at tau 1 and 2) and Table 3 (needed, real-time
//! loaded data and I/O time at frames along a flight), from `terrain bake`, `terrain info`
//! and `terrain bench --methods ooc` in the real-time streaming mode.

use serde_json::Value;

use super::doc::{Figure, PaperDoc, Section, Table, effect, lower_is_better, num, text};
use super::{Ctx, f, fps, frame_mean, runs};

/// The paper's Table 1 (DEM columns): dataset, original MB, after processing MB.
const PAPER_T1: [(&str, f64, f64); 3] = [
    ("Grand Canyon (4097 x 2049)", 16.04, 17.3),
    ("Puget Sound (16385 x 16385)", 512.0, 555.0),
    ("South-east of China (36006 x 30006)", 2.01 * 1024.0, 2.18 * 1024.0),
];

/// The paper's Table 2, Puget Sound rows: tau, triangles, fps, peak memory MB.
const PAPER_T2: [(f64, f64, f64, f64); 2] =
    [(1.0, 98_230.0, 40.0, 102.0), (2.0, 33_430.0, 67.0, 85.0)];

/// The paper's Table 3, Puget Sound columns: frame (of 10,000), needed MB, real-time MB, I/O ms.
const PAPER_T3: [(usize, f64, f64, f64); 8] = [
    (1, 1.307, 1.307, 21.3),
    (162, 1.975, 0.032, 0.59),
    (388, 2.445, 0.034, 0.97),
    (4509, 1.284, 0.007, 0.19),
    (5330, 1.719, 0.007, 0.16),
    (7374, 1.113, 0.008, 0.23),
    (8208, 2.267, 0.024, 0.30),
    (10000, 1.132, 0.014, 0.29),
];

fn median(mut v: Vec<f64>) -> f64 {
    v.retain(|x| x.is_finite());
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 { v[n / 2] } else { 0.5 * (v[n / 2 - 1] + v[n / 2]) }
}

const MIB: f64 = 1024.0 * 1024.0;

/// Table 1 from the stores: (name, info JSON).
fn table1(stores: &[(String, Value)]) -> Section {
    let mut s = Section::new("Table 1", "Experimental data: DEM size before and after processing");
    s.setup.push(
        "Original size: the grid at 16 bits per sample (the paper's Puget Sound: 16385^2 x 2 B = \
         512 MiB); after processing: the store's index plus block files (`terrain info --json`: \
         `bytes`). Our stores hold every sample once (the non-redundant levels of Eq. 1-2) and \
         compress each level (predictive coding + Deflate), which the paper does not."
            .into(),
    );
    s.setup.push(
        "Texture columns: not produced (the engine has no texture pipeline; the paper's DXT1 \
         mipmaps are outside what we implement)."
            .into(),
    );
    let mut t = Table::new(
        "DEM data, MiB.",
        &[
            "Dataset",
            "Grid",
            "Blocks",
            "Original size (16-bit)",
            "After processing",
            "After / original",
        ],
    );
    let mut levels = Vec::new();
    for (name, info) in stores {
        let (w, h) = (f(info, "width"), f(info, "height"));
        let raw = w * h * 2.0 / MIB;
        let after = f(info, "bytes") / MIB;
        t.rows.push(vec![
            text(name.clone()),
            text(format!("{w} x {h}")),
            text(format!(
                "{} x {} of {}^2",
                info["blocks"][0], info["blocks"][1], info["block_side"]
            )),
            num(raw, 2),
            num(after, 2),
            num(after / raw, 3),
        ]);
        let paper_ratio = PAPER_T1[1].2 / PAPER_T1[1].1;
        // A pyramid of full grids per level stores sum (2^n + 1)^2 / (2^k + 1)^2 of the samples.
        let side = f(info, "block_side");
        let k = (side - 1.0).log2().round() as i32;
        let pyramid: f64 =
            (0..=k).map(|n| (2f64.powi(n) + 1.0).powi(2)).sum::<f64>() / (side * side);
        s.verdicts.push(lower_is_better(
            format!("{name}: storage after processing against the original (paper: Puget Sound 555 / 512 MB)"),
            paper_ratio,
            after / raw,
            Some(0.05),
            pyramid,
        ));
        let stored: f64 = info["levels"]
            .as_array()
            .map_or(f64::NAN, |l| l.iter().map(|x| f(x, "vertices")).sum());
        let blocks = info["blocks"][0].as_f64().unwrap_or(f64::NAN)
            * info["blocks"][1].as_f64().unwrap_or(f64::NAN);
        s.verdicts.push(lower_is_better(
            format!(
                "{name}: non-redundant levels (Eq. 1-2): vertices stored per block vertex (a pyramid stores {pyramid:.3})"
            ),
            1.0,
            stored / (blocks * side * side),
            Some(0.001),
            pyramid,
        ));
        levels.push((name.clone(), info.clone(), blocks));
    }
    s.ours.push(t);
    let mut p = Table::new(
        "Table 1 (DEM columns), MB.",
        &["Dataset", "Original size", "After processing", "After / original"],
    );
    for (name, o, a) in PAPER_T1 {
        p.rows.push(vec![text(name), num(o, 2), num(a, 2), num(a / o, 3)]);
    }
    s.paper = Some(p);
    for (name, info, blocks) in levels {
        let mut t = Table::new(
            format!(
                "Storage per level, {name} (not in the paper: its Eq. 1-2 per level, summed over the {blocks} blocks; pyramid = a full (2^n + 1)^2 grid per level at 16 bits)."
            ),
            &[
                "Level n",
                "Eq. 1-2 new vertices per block",
                "Vertices stored",
                "Stored MiB",
                "Decoded MiB",
                "Pyramid MiB (16-bit)",
            ],
        );
        for l in info["levels"].as_array().into_iter().flatten() {
            let n = f(l, "level") as i32;
            let eq = (2f64.powi(n) + 1.0).powi(2)
                - if n == 0 { 0.0 } else { (2f64.powi(n - 1) + 1.0).powi(2) };
            t.rows.push(vec![
                num(f64::from(n), 0),
                num(eq, 0),
                num(f(l, "vertices"), 0),
                num(f(l, "disk_bytes") / MIB, 3),
                num(f(l, "decoded_bytes") / MIB, 3),
                num((2f64.powi(n) + 1.0).powi(2) * blocks * 2.0 / MIB, 3),
            ]);
        }
        s.ours.push(t);
    }
    s
}

/// Table 2 from the bench report of `ooc` at tau 1 and 2.
fn table2(report: &Value, dem: &str, flight: &str, budget_mib: f64) -> Section {
    let mut s = Section::new(
        "Table 2",
        "Frame rate, rendering complexity and peak memory while navigating",
    );
    s.setup.push(format!(
        "{dem}, flight `{flight}` played in real time at its own 30 fps (frames do not wait for \
         I/O after the first; the paper's one-frame Eq. 8 pre-loading), the measured frames \
         evenly spaced; averages over the measured frames. Frames per second: 1000 / mean \
         (selection + render wall) on this machine's software renderer (the paper: an NVIDIA \
         9800GT), so compare the ratio between tau 1 and 2, not the values. A measured frame's \
         measuring and drawing (seconds on the software renderer) stop the flight's clock and \
         hold the store's I/O (`Streamer::hold_io`): the workers get the flight's 30 fps \
         periods only, as if every frame took no longer than its period."
    ));
    s.setup.push(
        "Peak memory: the streamer's resident data (the paper's main memory for terrain) and, \
         beside it, the whole process's resident set (which also holds the full DEM for the \
         error measurement, the renderer and lavapipe)."
            .into(),
    );
    let mut t = Table::new(
        "",
        &[
            "Dataset",
            "tau",
            "Average triangles per frame",
            "Average frames per second",
            "Peak streamed data (MiB)",
            "Peak process RSS (MiB)",
            "Frames at their needed level",
        ],
    );
    let r = runs(report, "ooc", None);
    let mut by_tau = Vec::new();
    // Per tau: mean frame ms, mean drawing ms, mean needed MiB (the reasons below).
    let mut extra: Vec<(f64, f64, f64, f64)> = Vec::new();
    for run in &r {
        let tau = f(run, "value");
        let tri = frame_mean(run, "triangles");
        let rate = fps(run);
        let peak = f(run, "stream.peak_resident_mib");
        let rss = f(run, "summary.max_rss_bytes") / MIB;
        t.rows.push(vec![
            text(dem),
            num(tau, 0),
            num(tri, 0),
            num(rate, 1),
            num(peak, 2),
            num(rss, 0),
            text(format!("{:.1} %", 100.0 * f(run, "stream.at_needed_level_share"))),
        ]);
        by_tau.push((tau, tri, rate, peak));
        extra.push((
            tau,
            frame_mean(run, "frame_ms"),
            frame_mean(run, "render_ms"),
            frame_mean(run, "stream.needed_mib"),
        ));
    }
    s.ours.push(t);
    let mut p = Table::new(
        "Puget Sound rows.",
        &["Dataset", "tau", "Average triangles per frame", "Average fps", "Peak memory (M)"],
    );
    for (tau, tri, fps, mem) in PAPER_T2 {
        p.rows.push(vec![text("Puget Sound"), num(tau, 0), num(tri, 0), num(fps, 0), num(mem, 0)]);
    }
    s.paper = Some(p);
    let get = |tau: f64| by_tau.iter().find(|x| x.0 == tau).copied();
    let (one, two) = (get(1.0), get(2.0));
    let nan = (f64::NAN, f64::NAN, f64::NAN, f64::NAN);
    let (one, two) = (one.unwrap_or(nan), two.unwrap_or(nan));
    let (p1, p2) = (PAPER_T2[0], PAPER_T2[1]);
    s.verdicts.push(effect(
        "tau 2 draws fewer triangles than tau 1 (ratio - 1)",
        p2.1 / p1.1 - 1.0,
        two.1 / one.1 - 1.0,
    ));
    let ex = |tau: f64| {
        extra.iter().find(|x| x.0 == tau).copied().unwrap_or((tau, f64::NAN, f64::NAN, f64::NAN))
    };
    let (e1, e2) = (ex(1.0), ex(2.0));
    s.verdicts.push(
        effect(
            "tau 2 renders more frames per second than tau 1 (ratio - 1)",
            p2.2 / p1.2 - 1.0,
            two.2 / one.2 - 1.0,
        )
        .because(|| {
            format!(
                "the mean frame takes {:.0} ms at tau 1 and {:.0} ms at tau 2 ({:+.1} %), of \
                 which drawing (lavapipe's wall time) {:.0} and {:.0} ms ({:+.1} %), for {:+.1} % \
                 triangles: the software renderer's per-pixel work at the image size does not \
                 shrink with the triangles as the paper's GPU's frame does",
                e1.1,
                e2.1,
                100.0 * (e2.1 / e1.1 - 1.0),
                e1.2,
                e2.2,
                100.0 * (e2.2 / e1.2 - 1.0),
                100.0 * (two.1 / one.1 - 1.0)
            )
        }),
    );
    s.verdicts.push(
        effect(
            "tau 2 needs less peak memory than tau 1 (ratio - 1; ours: streamed data)",
            p2.3 / p1.3 - 1.0,
            two.3 / one.3 - 1.0,
        )
        .because(|| {
            format!(
                "the streamed data peaks at {:.2} MiB at tau 1 and {:.2} MiB at tau 2 against the \
                 cache budget of {budget_mib:.0} MiB (kept above it when a frame needs more): the \
                 streamer fills its budget with pre-loaded levels whatever tau, so the peak is \
                 the budget's or the frames' need; the data the mean frame needs: {:.2} MiB at \
                 tau 1, {:.2} MiB at tau 2 ({:+.1} %; the paper's peak memory {:+.1} %)",
                one.3,
                two.3,
                e1.3,
                e2.3,
                100.0 * (e2.3 / e1.3 - 1.0),
                100.0 * (p2.3 / p1.3 - 1.0)
            )
        }),
    );
    s
}

/// Our "real-time loading data" of a frame: what it loaded on the frame thread, waited for, or
/// lacked when drawn (late), MiB.
fn realtime_mib(stream: &Value) -> f64 {
    let waited = stream["waited_for_io"].as_bool().unwrap_or(false);
    f(stream, "sync_mib")
        + f(stream, "late_mib")
        + if waited { f(stream, "prefetched_mib") } else { 0.0 }
}

/// Table 3 from the tau-2 run: rows at the measured frames nearest the paper's positions.
fn table3(report: &Value, dem: &str, flight: &str, store_mib: f64) -> Section {
    let mut s = Section::new("Table 3", "Results of loading data and scheduling time (tau = 2)");
    let run = runs(report, "ooc", None).into_iter().find(|r| f(r, "value") == 2.0);
    let frames: Vec<&Value> =
        run.and_then(|r| r["frames"].as_array()).map(|v| v.iter().collect()).unwrap_or_default();
    let total = report["flights"][0]["total_frames"].as_f64().unwrap_or(f64::NAN);
    s.setup.push(format!(
        "{dem}, flight `{flight}` ({total} frames at 30 fps, real time). The paper's frame k of \
         10,000 maps to our frame round((k - 1) / 9999 x (N - 1)); each row is the measured \
         frame nearest it. Real-time loading data: what the frame loaded on the frame thread, \
         waited for from the workers, or lacked when drawn (late: drawn at a coarser resident \
         level instead of waiting); pre-loaded: what the workers delivered since the last \
         frame (the one-frame Eq. 8 look-ahead's requests and the visible blocks' missing \
         levels); I/O time: synchronous reads plus the workers' reads that arrived that frame. \
         MiB (the paper's M). The measured frames hold the I/O while measured and drawn (as in \
         Table 2), so each row's late data is what one 30 fps period left undone."
    ));
    if let Some(r) = run {
        s.setup.push(format!(
            "Whole flight: {} frames played, {} waited for I/O after the first, {:.1} % drawn at \
             their needed level, late data per frame median {:.3} MiB and at most {:.3} MiB, \
             {:.3} MiB pre-loaded per frame on average, {} frames started behind the 30 fps \
             schedule.",
            r["stream"]["frames"],
            r["stream"]["waited_after_first"],
            100.0 * f(r, "stream.at_needed_level_share"),
            f(r, "stream.late_mib_median"),
            f(r, "stream.late_mib_max"),
            f(r, "stream.prefetched_mib_mean"),
            r["stream"]["behind_schedule"]
        ));
    }
    let first_need = frames.first().map_or(f64::NAN, |fr| f(&fr["stream"], "needed_mib"));
    s.setup.push(format!(
        "The first frame needs {first_need:.3} MiB of the store's {store_mib:.3} MiB (all levels \
         decoded){}",
        if first_need >= 0.9 * store_mib {
            ": nearly the whole store, which then stays resident (the cache never evicts below \
             what a frame needs), so later frames have little or nothing to load and this run \
             does not exercise the pre-loading"
        } else {
            "."
        }
    ));
    let mut t = Table::new(
        "",
        &[
            "Frame (paper's)",
            "Our frame",
            "Needed data (MiB)",
            "Real-time loading data (MiB)",
            "of which late (MiB)",
            "Pre-loaded (MiB)",
            "I/O time (ms)",
        ],
    );
    let mut shares = Vec::new();
    let mut ios = Vec::new();
    let mut used = Vec::new();
    for (k, (pf, ..)) in PAPER_T3.iter().enumerate() {
        let target = ((*pf as f64 - 1.0) / 9999.0 * (total - 1.0)).round();
        let near = frames.iter().min_by(|a, b| {
            (f(a, "frame") - target).abs().total_cmp(&(f(b, "frame") - target).abs())
        });
        // A row whose nearest measured frame an earlier row took is left out (few frames).
        let Some(fr) = near.filter(|fr| !used.contains(&f(fr, "frame"))) else { continue };
        used.push(f(fr, "frame"));
        let st = &fr["stream"];
        let (need, rt, io) = (f(st, "needed_mib"), realtime_mib(st), f(st, "io_ms"));
        t.rows.push(vec![
            num(*pf as f64, 0),
            num(f(fr, "frame"), 0),
            num(need, 3),
            num(rt, 3),
            num(f(st, "late_mib"), 3),
            num(f(st, "prefetched_mib"), 3),
            num(io, 2),
        ]);
        if k > 0 {
            shares.push(rt / need);
            ios.push(io);
        }
    }
    let first_io = t.rows.first().map_or(f64::NAN, |r| match r[6] {
        super::doc::Cell::Num(v, _) => v,
        _ => f64::NAN,
    });
    s.ours.push(t);
    let mut p = Table::new(
        "Puget Sound columns.",
        &["Frame series number", "Needed data (M)", "Real-time loading data (M)", "I/O time (ms)"],
    );
    for (fr, need, rt, io) in PAPER_T3 {
        p.rows.push(vec![num(fr as f64, 0), num(need, 3), num(rt, 3), num(io, 2)]);
    }
    s.paper = Some(p);
    let paper_share = median(PAPER_T3[1..].iter().map(|r| r.2 / r.1).collect());
    let paper_io = median(PAPER_T3[1..].iter().map(|r| r.3).collect()) / PAPER_T3[0].3;
    let late_rows = shares.iter().filter(|&&x| x > 0.0).count();
    let whole = |key: &str| run.map_or(f64::NAN, |r| f(r, &format!("stream.{key}")));
    let flight_why = || {
        format!(
            "{late_rows} of the {} rows after the first lacked data when drawn; over the whole \
             flight {:.1} % of the frames were drawn at their needed level, the late data per \
             frame was {:.3} MiB at the median and {:.3} MiB at most (the median frame needs \
             {:.3} MiB), {:.3} MiB arrived pre-loaded per frame on average, and {} of the \
             frames started behind the 30 fps schedule",
            shares.len(),
            100.0 * whole("at_needed_level_share"),
            whole("late_mib_median"),
            whole("late_mib_max"),
            whole("needed_mib_median"),
            whole("prefetched_mib_mean"),
            run.map_or(Value::Null, |r| r["stream"]["behind_schedule"].clone())
        )
    };
    s.verdicts.push(
        lower_is_better(
            "after frame 1, pre-loading keeps the real-time loaded data a small share of the needed data (median share over the rows after the first)",
            paper_share,
            median(shares.clone()),
            None,
            1.0,
        )
        .because(flight_why),
    );
    s.verdicts.push(
        lower_is_better(
            "the same over the whole flight: median late data per frame / median needed data per frame (every frame played, not only the rows)",
            paper_share,
            whole("late_mib_median") / whole("needed_mib_median"),
            None,
            1.0,
        )
        .because(flight_why),
    );
    s.verdicts.push(
        lower_is_better(
            "after frame 1, the I/O time per frame is a small fraction of frame 1's (median over the rows after the first / frame 1)",
            paper_io,
            median(ios.clone()) / first_io,
            None,
            1.0,
        )
        .because(|| {
            format!(
                "frame 1 read for {first_io:.2} ms; the rows after it {} ms: the workers' reads \
                 that arrived in a frame (per-frame I/O time, not the frame thread's: ours \
                 never reads on the frame thread after frame 1)",
                ios.iter().map(|x| format!("{x:.2}")).collect::<Vec<_>>().join(", ")
            )
        }),
    );
    let series = |key: &str| -> Vec<(f64, f64)> {
        frames
            .iter()
            .map(|fr| {
                (
                    f(fr, "frame"),
                    if key == "rt" { realtime_mib(&fr["stream"]) } else { f(&fr["stream"], key) },
                )
            })
            .collect()
    };
    s.figures.push(Figure {
        file: "table3.svg".into(),
        title: format!("ooc, tau 2, {dem}, {flight}: data per measured frame"),
        x_label: "frame".into(),
        y_label: "MiB".into(),
        series: vec![
            ("needed".into(), series("needed_mib")),
            ("real-time loaded".into(), series("rt")),
            ("prefetched".into(), series("prefetched_mib")),
        ],
    });
    s
}

/// Runs the out-of-core paper's tables.
pub(crate) fn run(ctx: &mut Ctx) -> anyhow::Result<PaperDoc> {
    let ps1k = ctx.puget1k()?;
    let (store1k, info1k) = bake(ctx, "ps1k", &ps1k)?;
    let mut stores = vec![("Puget Sound 1k (ps_height_1k.png)".to_string(), info1k.clone())];
    // Tables 2-3: the 1k map in --quick; the 4k map in full runs, whose far blocks need
    // coarser levels than the near ones (on the 1k map every frame needs nearly every level).
    let (ps, store, info, dem, cache_mib) = if ctx.quick {
        (ps1k, store1k, info1k, "Puget Sound 1k", "1")
    } else {
        let ps4k = ctx.puget4k()?;
        let (store4k, info4k) = bake(ctx, "ps4k", &ps4k)?;
        stores.push(("Puget Sound 4k (ps_height_4k.jpg)".to_string(), info4k.clone()));
        (ps4k, store4k, info4k, "Puget Sound 4k", "16")
    };
    // The stores named with --store, in Table 1 of quick runs too (only `terrain info`).
    for (name, dir) in ctx.stores.clone() {
        stores.push((name, ctx.store_info(&dir)?));
    }
    let (flight, frames, size) = if ctx.quick {
        ("fast_pass.json", "8", "320x240")
    } else {
        ("pvps_884.json", "60", "1024x768")
    };
    let mut args = ps.clone();
    args.extend(
        [
            "--methods",
            "ooc",
            "--values",
            "1,2",
            "--flight",
            &ctx.flight(flight),
            "--frames",
            frames,
            "--viewport",
            "1024x768",
            "--size",
            size,
            "--ooc-store",
            &store.display().to_string(),
            "--ooc-cache-mib",
            cache_mib,
        ]
        .map(String::from),
    );
    let report = ctx.bench("ooc_tables23", &args)?;
    let decoded: f64 = info["levels"]
        .as_array()
        .map_or(f64::NAN, |l| l.iter().map(|x| f(x, "decoded_bytes")).sum())
        / MIB;
    Ok(PaperDoc {
        key: "ooc".into(),
        title: "Qiu et al. 2013, \"An Effective Visualization Method for Large-scale Terrain Dataset\" (the out-of-core paper)".into(),
        differences: vec![
            format!("Terrain: the shared Puget Sound map (the paper's middle dataset), {dem} for Tables 2-3 (full runs: the 4096^2 8-bit JPEG at about 40 m, terraced; --quick: the 1025^2 16-bit PNG at 160 m); the paper's is the 16385^2 original. Table 1 also lists the stores named with --store (their grids, baked by `terrain bake`)."),
            "Blocks of 257^2 vertices (k = 8, the store's default); the paper's are 1025^2.".into(),
            "Viewport 1024x768 as in the paper; the rendered image is the viewport in full runs (320x240 in --quick).".into(),
            "Hardware: a shared 2-core machine drawing with Mesa's software Vulkan (lavapipe); the paper: Windows XP, 2 GB, NVIDIA 9800GT. Frame rates compare by ratio only.".into(),
            format!("Flight `{flight}` (full runs: `pvps_884`, 60 s, 1800 frames; --quick: `fast_pass`, 10 s) where the paper flies 10,000 frames; Table 3's rows are mapped by position along the flight."),
            format!("Stream cache budget {cache_mib} MiB (the store decodes to {decoded:.1} MiB): under the default 256 MiB the whole store would stay resident after the first frames, leaving nothing to stream; the paper's peak memory is 85-102 MB for its 555 MB store. The streamer keeps at least what a frame needs whatever the budget."),
        ],
        commands: Vec::new(),
        load: Vec::new(),
        quick: false,
        sections: vec![table1(&stores), table2(&report, dem, flight, cache_mib.parse().unwrap_or(f64::NAN)), table3(&report, dem, flight, decoded)],
    })
}

/// Bakes the DEM `dem` (its `terrain` arguments) into the work folder's `stores/<name>` (the
/// blocks only) and returns the store and its `terrain info --json`.
pub(crate) fn bake(
    ctx: &mut Ctx,
    name: &str,
    dem: &[String],
) -> anyhow::Result<(std::path::PathBuf, Value)> {
    let store = ctx.work.join("stores").join(name);
    let mut args = vec!["bake".to_string()];
    args.extend(dem.iter().cloned());
    args.extend(
        [
            "-o",
            &store.display().to_string(),
            "--overwrite",
            "--no-pvs",
            "--no-dss",
            "--no-roughness",
            "--no-geomip",
        ]
        .map(String::from),
    );
    ctx.terrain(&args)?;
    let info = ctx.store_info(&store)?;
    Ok((store, info))
}
