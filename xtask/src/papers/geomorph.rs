//! The geomorphing article (Wagner 2003): Table 1 (frame rates of static geo-mipmapping,
//! software (CPU) morphing and hardware (vertex-shader) morphing, in a minimum and a full
//! scene), from `terrain bench` runs of `geomorph-static`, `geomorph-cpu` and `geomorph` on
//! the same flight; and the article's PVS step (`geomorph-pvs` against `geomorph`: what the
//! conservative PVS saves in patches, triangles and frame time, and the error it keeps).

use serde_json::Value;

use super::doc::{PaperDoc, Section, Table, effect_towards, num, prediction, text};
use super::{Ctx, f, frame_mean, runs};

/// Table 1's columns: our method and the article's name.
const METHODS: [(&str, &str); 3] = [
    ("geomorph-static", "Static LOD"),
    ("geomorph-cpu", "Software Morphing"),
    ("geomorph", "Hardware Morphing"),
];

/// The article's Table 1 (fps): minimum scene, full scene; static, software, hardware.
const PAPER: [[f64; 3]; 2] = [[504.0, 312.0, 501.0], [231.0, 205.0, 230.0]];

/// The scenes: label, whether the bench colours patches by level (one pass).
const SCENES: [(&str, bool); 2] = [("Minimum scene", true), ("Full scene", false)];

/// The median of `key` over a run's frames; `NaN` for none.
fn frame_median(run: &Value, key: &str) -> f64 {
    let mut v: Vec<f64> = run["frames"]
        .as_array()
        .map(|fr| fr.iter().map(|x| f(x, key)).filter(|x| x.is_finite()).collect())
        .unwrap_or_default();
    v.sort_by(f64::total_cmp);
    match v.len() {
        0 => f64::NAN,
        n if n % 2 == 1 => v[n / 2],
        n => 0.5 * (v[n / 2 - 1] + v[n / 2]),
    }
}

/// Per method: fps (1000 / the median frame time: the first frame of a path also builds its
/// pipeline, and the shared machine's load spikes), median frame ms, mean CPU build ms (the
/// CPU morph), mean upload bytes, mean triangles.
fn figures(report: &Value, method: &str) -> [f64; 5] {
    match runs(report, method, None).first() {
        Some(r) => [
            1000.0 / frame_median(r, "frame_ms"),
            frame_median(r, "frame_ms"),
            frame_mean(r, "cpu_ms") - frame_mean(r, "encode_ms") - frame_mean(r, "selection_ms"),
            frame_mean(r, "upload_bytes"),
            frame_mean(r, "triangles"),
        ],
        None => [f64::NAN; 5],
    }
}

/// Runs Table 1.
pub(crate) fn run(ctx: &mut Ctx) -> anyhow::Result<PaperDoc> {
    let ps = ctx.puget1k()?;
    let (frames, size) = if ctx.quick { ("4", "320x180") } else { ("30", "640x360") };
    let mut ours = Vec::new();
    for (scene, lod_colours) in SCENES {
        let mut args = ctx.flight_args(
            &ps,
            "valley_low.json",
            "geomorph-static,geomorph-cpu,geomorph",
            "1",
            frames,
            size,
        );
        if lod_colours {
            args.push("--lod-colours".into());
        }
        let name = if lod_colours { "geomorph_minimum" } else { "geomorph_full" };
        let report = ctx.bench(name, &args)?;
        ours.push((scene, METHODS.map(|(m, _)| figures(&report, m))));
    }
    let setting = format!(
        "Puget Sound 1k (1025^2, 160 m), flight `valley_low`, {frames} frames evenly spaced, \
         tau = 1 px on a 1280x720 view (the geomorph default), patches of 17 x 17 vertices and \
         5 levels (the article's), rendered at {size} by the geomorph renderer on software \
         Vulkan (lavapipe). fps = 1000 / mean frame time (selection + the CPU morph where there \
         is one + the renderer's wall time, waiting for the device), the median over the frames \
         (the article's figures are averages; a path's first frame also builds its pipeline, \
         and the shared machine's load spikes)."
    );
    let mut s = Section::new("Table 1", "Frame rates at different scene setups and LOD systems");
    s.setup.push(setting);
    s.setup.push(
        "Minimum scene: `terrain bench --lod-colours`: one pass per patch, its level's colour \
         lit by the lightmap (the article: one material and the lightmap, 2 textures in one \
         pass). Full scene: the renderer's base pass and its alpha-blended material passes \
         (up to 5 passes, each skipped on patches the material does not reach); the article's \
         full scene also draws a cloud-shadow layer, a skybox and a lens flare, which we do \
         not have: our full scene is the article's terrain passes only."
            .into(),
    );
    s.setup.push(
        "Software morphing: every vertex of every drawn patch morphed on the CPU by the morph's \
         reference (`MorphGrid::patch_heights`, the code the vertex shader's morph is tested \
         against, and whose upload draws the same image: \
         `geomorph::tests::cpu_morph_draws_the_shaders_morph_vulkan`), uploaded every frame \
         (4 bytes per vertex) and drawn by a pipeline that reads the heights and does not \
         morph. On lavapipe the 'GPU' is the same two CPU cores and the 'bus' a memory copy, \
         so the article's bus-transfer cost is nearly absent while the CPU morph competes with \
         the rasteriser for the cores: compare ratios, not absolute fps."
            .into(),
    );
    let mut t = Table::new(
        "Frames per second (ours).",
        &["Scene", "Static LOD", "Software Morphing", "Hardware Morphing"],
    );
    for (scene, f) in &ours {
        t.rows.push(std::iter::once(text(*scene)).chain(f.iter().map(|x| num(x[0], 1))).collect());
    }
    s.ours.push(t);
    let mut d = Table::new(
        "Per frame: median frame time; means of the CPU morph (software morphing's build \
         stage), the bytes uploaded and the triangles drawn (static LOD: the same levels with \
         every tween factor 0, so the same triangles).",
        &["Scene", "Method", "Frame (ms)", "CPU morph (ms)", "Upload (KiB)", "Triangles"],
    );
    for (scene, f) in &ours {
        for ((m, _), x) in METHODS.iter().zip(f) {
            d.rows.push(vec![
                text(*scene),
                text(*m),
                num(x[1], 2),
                num(x[2].max(0.0), 2),
                num(x[3] / 1024.0, 1),
                num(x[4], 0),
            ]);
        }
    }
    s.ours.push(d);
    let mut p = Table::new(
        "Table 1 (Athlon-1300, GeForce3), fps.",
        &["Scene", "Static LOD", "Software Morphing", "Hardware Morphing"],
    );
    for ((scene, _), r) in SCENES.iter().zip(PAPER) {
        p.rows.push(std::iter::once(text(*scene)).chain(r.iter().map(|&v| num(v, 0))).collect());
    }
    s.paper = Some(p);
    let ratio = |f: &[[f64; 5]; 3], k: usize| f[k][0] / f[0][0];
    for (i, (scene, f)) in ours.iter().enumerate() {
        let pr = PAPER[i];
        s.verdicts.push(
            prediction(
                format!(
                    "{scene}: hardware morphing is almost as fast as static LOD (fps ratio \
                 hardware / static at least 0.95; the article's {:.3})",
                    pr[2] / pr[0]
                ),
                0.95,
                ratio(f, 2),
                true,
            )
            .because(|| {
                format!(
                    "on lavapipe the vertex stage runs on the same CPU cores: the morph in the \
                 vertex shader adds {:.1} ms per frame ({:.1} -> {:.1} ms median) for the same \
                 {:.0} triangles and the same {:.0} KiB of upload, where the article's GeForce3 \
                 ran it in its vertex unit",
                    f[2][1] - f[0][1],
                    f[0][1],
                    f[2][1],
                    f[0][4],
                    f[0][3] / 1024.0
                )
            }),
        );
        s.verdicts.push(
            effect_towards(
                format!("{scene}: software morphing is slower than static LOD (fps ratio - 1)"),
                -1.0,
                pr[1] / pr[0] - 1.0,
                ratio(f, 1) - 1.0,
            )
            .because(|| {
                format!(
                    "the CPU morph takes {:.2} ms and {:.0} KiB more upload per frame, {:.1} % \
                     of the {:.0} ms static frame that lavapipe's drawing fills (the article's \
                     cost was the bus transfer of those bytes, a memory copy here); the fps \
                     differ by {:+.1} %, so frame-to-frame variation outweighs the morph",
                    f[1][2],
                    (f[1][3] - f[0][3]) / 1024.0,
                    100.0 * f[1][2] / f[0][1],
                    f[0][1],
                    100.0 * (ratio(f, 1) - 1.0)
                )
            }),
        );
    }
    if let [(_, min), (_, full)] = ours.as_slice() {
        s.verdicts.push(
            effect_towards(
                "software morphing falls back less in the full scene than in the minimum one \
             (its software/static ratio, full over minimum, - 1)",
                1.0,
                (PAPER[1][1] / PAPER[1][0]) / (PAPER[0][1] / PAPER[0][0]) - 1.0,
                ratio(full, 1) / ratio(min, 1) - 1.0,
            )
            .because(|| {
                format!(
                    "the CPU morph is {:.1} % of the static frame in the minimum scene and \
                     {:.1} % in the full one, while the software/static fps ratios are {:.3} \
                     and {:.3}: the morph's own cost is below the frame-to-frame variation of \
                     lavapipe on this shared machine, so the ratio between the scenes measures \
                     that variation",
                    100.0 * min[1][2] / min[0][1],
                    100.0 * full[1][2] / full[0][1],
                    ratio(min, 1),
                    ratio(full, 1)
                )
            }),
        );
    }
    let pvs = pvs_section(ctx, &ps, frames, size)?;
    Ok(PaperDoc {
        key: "geomorph".into(),
        title:
            "Wagner 2003, \"Terrain Geomorphing in the Vertex Shader\" (the geomorphing article)"
                .into(),
        differences: vec![
            "Terrain: the shared Puget Sound map at 1025^2 (the article's terrain is an 8-bit \
             heightmap of unstated size in 17 x 17 patches, as ours)."
                .into(),
            "Hardware: software Vulkan (lavapipe) on a shared 2-core machine against the \
             article's Athlon-1300 and GeForce3: the vertex and fragment stages run on the same \
             CPU cores as the CPU morph, and uploads are memory copies. Frame rates compare by \
             ratio only."
                .into(),
            "PVS: Table 1's rows draw every patch in the frustum; the article's PVS step is the \
             separate method `geomorph-pvs` (docs/papers.md), measured in its own section (the \
             article gives no figure for it)."
                .into(),
        ],
        commands: Vec::new(),
        load: Vec::new(),
        quick: false,
        sections: vec![s, pvs],
    })
}

/// Per run: mean patches, mean triangles, median frame ms, median p99 px, false culls (the
/// measured samples a culled patch hid that were visible).
fn pvs_figures(report: &Value, method: &str) -> [f64; 5] {
    match runs(report, method, None).first() {
        Some(r) => [
            frame_mean(r, "patches"),
            frame_mean(r, "triangles"),
            frame_median(r, "frame_ms"),
            f(r, "summary.median_p99_px"),
            f(r, "summary.false_culls"),
        ],
        None => [f64::NAN; 5],
    }
}

/// The article's PVS layers in use: `geomorph` and `geomorph-pvs` on the same flight.
fn pvs_section(ctx: &mut Ctx, ps: &[String], frames: &str, size: &str) -> anyhow::Result<Section> {
    let args = ctx.flight_args(ps, "valley_low.json", "geomorph,geomorph-pvs", "1", frames, size);
    let report = ctx.bench("geomorph_pvs", &args)?;
    let mut s = Section::new(
        "PVS",
        "The article's PVS step: geomorphing with and without the patches the PVS hides",
    );
    s.setup.push(format!(
        "Puget Sound 1k, flight `valley_low` (low in a valley, where terrain hides terrain), \
         {frames} frames evenly spaced, tau = 1 px, the full scene rendered at {size}. \
         `geomorph-pvs` is `geomorph` (vertex-shader morph) less the patches the PVS proves \
         hidden from the camera's view cell (`MethodScene::cull_geomorph_pvs`), with the \
         conservative bake (a patch is culled only when no sample of it is visible from any \
         point of the cell) instead of the article's line-of-sight samples, baked in memory at \
         the default view cells. The article describes the step and gives no figure for it."
    ));
    let (without, with) = (pvs_figures(&report, "geomorph"), pvs_figures(&report, "geomorph-pvs"));
    // Frame time paired by frame: with / without on the same frame of the flight; the
    // median ratio and its interquartile range (the measurement's noise: the same frame
    // drawn twice on the shared machine).
    let paired: Vec<f64> = {
        let per_frame = |m: &str| -> Vec<(f64, f64)> {
            runs(&report, m, None)
                .first()
                .and_then(|r| r["frames"].as_array())
                .map(|fr| fr.iter().map(|x| (f(x, "frame"), f(x, "frame_ms"))).collect())
                .unwrap_or_default()
        };
        let (a, b) = (per_frame("geomorph"), per_frame("geomorph-pvs"));
        let mut v: Vec<f64> = a
            .iter()
            .filter_map(|&(k, t)| b.iter().find(|x| x.0 == k).map(|x| x.1 / t))
            .filter(|x| x.is_finite())
            .collect();
        v.sort_by(f64::total_cmp);
        v
    };
    let q = |p: f64| {
        paired.get(((paired.len() as f64 - 1.0) * p).round() as usize).copied().unwrap_or(f64::NAN)
    };
    let (q1, ratio, q3) = (q(0.25), q(0.5), q(0.75));
    s.setup.push(format!(
        "Frame time paired by frame: `geomorph-pvs` / `geomorph` on the same frame, median \
         {ratio:.3}, interquartile range {q1:.3} to {q3:.3} over the {} frames (the spread is \
         the shared machine's noise between two draws of one frame).",
        paired.len()
    ));
    let mut t = Table::new(
        "Means of patches and triangles, medians of frame time and p99 screen error over the \
         frames; false culls: measured DEM samples inside culled patches that are visible.",
        &["Method", "Patches", "Triangles", "Frame (ms)", "p99 error (px)", "False culls"],
    );
    for (m, x) in [("geomorph", without), ("geomorph-pvs", with)] {
        t.rows.push(vec![
            text(m),
            num(x[0], 1),
            num(x[1], 0),
            num(x[2], 1),
            num(x[3], 3),
            num(x[4], 0),
        ]);
    }
    t.rows.push(vec![
        text("with / without - 1"),
        text(format!("{:+.2} %", 100.0 * (with[0] / without[0] - 1.0))),
        text(format!("{:+.2} %", 100.0 * (with[1] / without[1] - 1.0))),
        text(format!("{:+.2} %", 100.0 * (with[2] / without[2] - 1.0))),
        text(format!("{:+.2} %", 100.0 * (with[3] / without[3] - 1.0))),
        text(""),
    ]);
    s.ours.push(t);
    s.verdicts.push(prediction(
        "the PVS removes hidden patches: fewer patches with it (ratio with / without at most \
         0.999)",
        0.999,
        with[0] / without[0],
        false,
    ));
    s.verdicts.push(prediction(
        "the PVS removes triangles (ratio with / without at most 0.999)",
        0.999,
        with[1] / without[1],
        false,
    ));
    s.verdicts.push(prediction(
        "no visible patch is culled: false culls at most 0 (the conservative bake)",
        0.0,
        with[4],
        false,
    ));
    s.verdicts.push(prediction(
        "the image's error is not raised: p99 px ratio with / without at most 1.01",
        1.01,
        with[3] / without[3],
        false,
    ));
    s.verdicts.push(
        prediction(
            "the saved triangles make the frame faster: median of the per-frame frame-time \
             ratios with / without at most 1",
            1.0,
            ratio,
            false,
        )
        .because(|| {
            let saved = 1.0 - with[1] / without[1];
            let noise = if q3 - q1 > saved {
                "wider than the triangles saved: two draws of one frame on lavapipe on the \
                 shared machine differ by more than the saving"
            } else {
                "narrower than the triangles saved, so the frame did not get faster with them"
            };
            format!(
                "{:+.2} % triangles; the per-frame ratio's interquartile range, {q1:.3} to \
                 {q3:.3}, is {noise}",
                -100.0 * saved
            )
        }),
    );
    Ok(s)
}
