//! The PVPS paper (Zhang 2021): Table 2 (methods A, B and C, C with and without the PVS, at
//! the four flight heights) and Table 3 (the C3/C4 sweep of Eq. 12), from `terrain bench`.

use serde_json::Value;

use super::doc::{PaperDoc, Section, Table, effect, num, text};
use super::{Ctx, f, fps, frame_mean, runs};

/// The flights and the paper's average camera heights.
const HEIGHTS: [(&str, u32); 4] =
    [("pvps_884", 884), ("pvps_1012", 1012), ("pvps_1140", 1140), ("pvps_1268", 1268)];

/// The paper's Table 2: height, method, fps, patches, triangles (its method C is with PVPS
/// culling).
const PAPER_T2: [(u32, &str, f64, f64, f64); 12] = [
    (884, "A", 3445.0, 92.0, 115_269.0),
    (884, "B", 3567.0, 104.0, 110_194.0),
    (884, "C", 4279.0, 68.0, 79_063.0),
    (1012, "A", 3433.0, 91.0, 116_540.0),
    (1012, "B", 3521.0, 103.0, 112_497.0),
    (1012, "C", 3884.0, 73.0, 89_391.0),
    (1140, "A", 3357.0, 90.0, 117_139.0),
    (1140, "B", 3444.0, 102.0, 116_505.0),
    (1140, "C", 3764.0, 81.0, 102_119.0),
    (1268, "A", 3304.0, 88.0, 118_157.0),
    (1268, "B", 3392.0, 101.0, 117_094.0),
    (1268, "C", 3557.0, 83.0, 105_194.0),
];

/// The paper's Table 3: C3, C4, triangles, fps.
const PAPER_T3: [(f64, f64, f64, f64); 3] =
    [(10.0, 1.0, 112_868.0, 1921.0), (12.5, 0.5, 72_314.0, 2223.0), (15.0, 0.25, 83_470.0, 2295.0)];

/// Our methods in Table 2's rows: CLI name and the row label.
const METHODS: [(&str, &str); 4] = [
    ("pvps-a", "Method A (stand-in, see docs/papers.md)"),
    ("pvps-b", "Method B"),
    ("pvps-c", "Method C without the PVS"),
    ("pvps-c-pvs", "Method C (with PVPS culling)"),
];

fn paper_row(h: u32, m: &str) -> (f64, f64, f64) {
    PAPER_T2
        .iter()
        .find(|r| r.0 == h && r.1 == m)
        .map_or((f64::NAN, f64::NAN, f64::NAN), |r| (r.2, r.3, r.4))
}

/// (fps, patches, triangles, false culls) of `method` on `flight`.
fn ours(report: &Value, method: &str, flight: &str) -> (f64, f64, f64, f64) {
    match runs(report, method, Some(flight)).first() {
        Some(r) => (
            fps(r),
            frame_mean(r, "patches"),
            frame_mean(r, "triangles"),
            f(r, "summary.false_culls"),
        ),
        None => (f64::NAN, f64::NAN, f64::NAN, f64::NAN),
    }
}

fn table2(report: &Value, setting: &str) -> Section {
    let mut s = Section::new("Table 2", "Comparison among different methods (four flight heights)");
    s.setup.push(setting.to_string());
    s.setup.push(
        "Averages over the measured frames. Frames per second: 1000 / mean (selection + render \
         wall time) on this machine's software renderer; the paper's are GPU frame rates on a \
         GTX 1660Ti: compare ratios between methods."
            .into(),
    );
    let mut t = Table::new(
        "",
        &[
            "Average camera height (m)",
            "Method",
            "Average frame rate (frame/s)",
            "Average number of patches",
            "Average number of triangles",
            "False culls (sum)",
        ],
    );
    for (flight, h) in HEIGHTS {
        for (m, label) in METHODS {
            let (rate, patches, tri, fc) = ours(report, m, flight);
            t.rows.push(vec![
                num(f64::from(h), 0),
                text(label),
                num(rate, 1),
                num(patches, 0),
                num(tri, 0),
                num(fc, 0),
            ]);
        }
    }
    s.ours.push(t);
    let mut p = Table::new(
        "",
        &[
            "Average camera height (m)",
            "Method",
            "Average frame rate (frame/s)",
            "Average number of patches",
            "Average number of triangles",
        ],
    );
    for (h, m, rate, patches, tri) in PAPER_T2 {
        p.rows.push(vec![
            num(f64::from(h), 0),
            text(format!("Method {m}")),
            num(rate, 0),
            num(patches, 0),
            num(tri, 0),
        ]);
    }
    s.paper = Some(p);
    let mut gains = Vec::new();
    for (flight, h) in HEIGHTS {
        let c = ours(report, "pvps-c-pvs", flight);
        let pc = paper_row(h, "C");
        let no_pvs = ours(report, "pvps-c", flight);
        // The measured split of C's gain: the roughness-weighted split alone (C without the
        // PVS against the other method) and the PVS's own culling (C with against without).
        let culled = c.2 / no_pvs.2 - 1.0;
        let why_split = |o: (f64, f64, f64, f64), other: &str, what: usize| {
            let pick = |x: (f64, f64, f64, f64)| if what == 1 { x.1 } else { x.2 };
            let noun = if what == 1 { "patches" } else { "triangles" };
            format!(
                "C's {noun} against {other}: {:+.1} % from the roughness-weighted split alone \
                 (C without the PVS), {:+.1} % more from the PVS ({:.1} -> {:.1} {noun}); the \
                 paper credits its whole gain to PVPS culling, which hides little on these \
                 flights",
                100.0 * (pick(no_pvs) / pick(o) - 1.0),
                100.0 * (pick(c) / pick(no_pvs) - 1.0),
                pick(no_pvs),
                pick(c)
            )
        };
        for other in ["A", "B"] {
            let o = ours(report, if other == "A" { "pvps-a" } else { "pvps-b" }, flight);
            let po = paper_row(h, other);
            s.verdicts.push(
                effect(
                    format!(
                        "{h} m: method C draws fewer triangles than method {other} (ratio - 1)"
                    ),
                    pc.2 / po.2 - 1.0,
                    c.2 / o.2 - 1.0,
                )
                .because(|| why_split(o, other, 2)),
            );
            s.verdicts.push(
                effect(
                    format!("{h} m: method C sends fewer patches than method {other} (ratio - 1)"),
                    pc.1 / po.1 - 1.0,
                    c.1 / o.1 - 1.0,
                )
                .because(|| why_split(o, other, 1)),
            );
            s.verdicts.push(
                effect(
                    format!(
                        "{h} m: method C renders at a higher frame rate than method {other} \
                         (ratio - 1)"
                    ),
                    pc.0 / po.0 - 1.0,
                    c.0 / o.0 - 1.0,
                )
                .because(|| {
                    format!(
                        "C draws {:.0} triangles a frame against {other}'s {:.0} ({:+.1} %) and \
                         renders at {:.2} against {:.2} frames/s: at a few thousand triangles \
                         (Eq. 12 in NDC, docs/papers.md) lavapipe's frame time does not \
                         follow the triangle count",
                        c.2,
                        o.2,
                        100.0 * (c.2 / o.2 - 1.0),
                        c.0,
                        o.0
                    )
                }),
            );
        }
        s.verdicts.push(
            effect(
                format!(
                    "{h} m: PVPS culling itself removes triangles (C with / without the PVS - 1; \
                     the paper credits C's whole gain over A to it)"
                ),
                pc.2 / paper_row(h, "A").2 - 1.0,
                culled,
            )
            .because(|| {
                format!(
                    "the PVS hides {:.1} of C's {:.1} patches a frame ({:.1} -> {:.1} \
                     triangles): little of the terrain in view is occluded on this flight; C's gain over A comes from its split ({:+.1} % \
                     triangles without the PVS)",
                    no_pvs.1 - c.1,
                    no_pvs.1,
                    no_pvs.2,
                    c.2,
                    100.0 * (no_pvs.2 / ours(report, "pvps-a", flight).2 - 1.0)
                )
            }),
        );
        let a = ours(report, "pvps-a", flight);
        gains.push((h, c.0 / a.0 - 1.0, pc.0 / paper_row(h, "A").0 - 1.0));
    }
    if let (Some(lo), Some(hi)) = (gains.first(), gains.last()) {
        s.verdicts.push(effect(
            "the frame-rate gain of C over A shrinks with height (gain at 1268 m / gain at 884 m - 1)",
            hi.2 / lo.2 - 1.0,
            hi.1 / lo.1 - 1.0,
        ));
    }
    s
}

fn table3(reports: &[(f64, f64, Value)], setting: &str) -> Section {
    let mut s = Section::new(
        "Table 3",
        "Comparison of different adjustment coefficients (Eq. 12's C3, C4)",
    );
    s.setup.push(setting.to_string());
    s.setup.push(
        "The paper measured one view of a gentle valley; we average over the 884 m flight \
         (method C with PVPS culling, C1 = 50). A flat patch's inner factor is C3 x C4 x its \
         screen length, so the three settings' flat factors are 10, 6.25 and 3.75 (x length)."
            .into(),
    );
    let mut t = Table::new(
        "",
        &[
            "Adjustment parameters",
            "Number of triangles",
            "Frame rate (frame/s)",
            "p99 pixel error (median)",
        ],
    );
    let mut got = Vec::new();
    for (c3, c4, rep) in reports {
        let r = runs(rep, "pvps-c-pvs", None);
        let (tri, rate, p99) = r.first().map_or((f64::NAN, f64::NAN, f64::NAN), |r| {
            (frame_mean(r, "triangles"), fps(r), f(r, "summary.median_p99_px"))
        });
        t.rows.push(vec![
            text(format!("C3 = {c3}, C4 = {c4}")),
            num(tri, 0),
            num(rate, 1),
            num(p99, 2),
        ]);
        got.push((tri, rate));
    }
    s.ours.push(t);
    let mut p =
        Table::new("", &["Adjustment parameters", "Number of triangles", "Frame rate (frame/s)"]);
    for (c3, c4, tri, rate) in PAPER_T3 {
        p.rows.push(vec![text(format!("C3 = {c3}, C4 = {c4}")), num(tri, 0), num(rate, 0)]);
    }
    s.paper = Some(p);
    let nan = (f64::NAN, f64::NAN);
    let base = got.first().copied().unwrap_or(nan);
    let first = PAPER_T3[0];
    for (k, &(c3, c4, tri, rate)) in PAPER_T3.iter().enumerate().skip(1) {
        let o = got.get(k).copied().unwrap_or(nan);
        s.verdicts.push(effect(
            format!("C3 = {c3}, C4 = {c4} draws fewer triangles than C3 = 10, C4 = 1 (ratio - 1)"),
            tri / first.2 - 1.0,
            o.0 / base.0 - 1.0,
        ));
        s.verdicts.push(effect(
            format!("C3 = {c3}, C4 = {c4} renders faster than C3 = 10, C4 = 1 (ratio - 1)"),
            rate / first.3 - 1.0,
            o.1 / base.1 - 1.0,
        ));
    }
    s
}

/// Runs the PVPS paper's tables.
pub(crate) fn run(ctx: &mut Ctx) -> anyhow::Result<PaperDoc> {
    let ps = ctx.puget1k()?;
    let (frames, size) = if ctx.quick { ("3", "320x214") } else { ("20", "600x400") };
    let mut args = ps.clone();
    args.push("--flight".into());
    for (flight, _) in HEIGHTS {
        args.push(ctx.flight(&format!("{flight}.json")));
    }
    args.extend(
        [
            "--methods",
            "pvps-a,pvps-b,pvps-c,pvps-c-pvs",
            "--values",
            "50",
            "--frames",
            frames,
            "--viewport",
            "1200x800",
            "--size",
            size,
        ]
        .map(String::from),
    );
    let t2 = ctx.bench("pvps_table2", &args)?;
    let mut t3 = Vec::new();
    for (c3, c4, ..) in PAPER_T3 {
        let mut a = ps.clone();
        a.extend(
            [
                "--flight",
                &ctx.flight("pvps_884.json"),
                "--methods",
                "pvps-c-pvs",
                "--values",
                "50",
                "--pvps-c3-c4",
                &format!("{c3}:{c4}"),
                "--frames",
                frames,
                "--viewport",
                "1200x800",
                "--size",
                size,
            ]
            .map(String::from),
        );
        t3.push((c3, c4, ctx.bench(&format!("pvps_table3_{c3}_{c4}"), &a)?));
    }
    let setting = format!(
        "Puget Sound 1k (1025^2, 160 m), the flights `pvps_884` .. `pvps_1268` (flights/README.md: \
         the paper's heights scaled by relief), {frames} frames each evenly spaced, viewport \
         1200x800 (the paper's screen), rendered at {size}; C1 = 50 (Eq. 8; the paper gives no \
         value), C3 = 10, C4 = 1 (the paper's), the sampled PVS baked in memory at the default \
         view cells."
    );
    Ok(PaperDoc {
        key: "pvps".into(),
        title: "Zhang et al. 2021, \"A Method of Optimizing Terrain Rendering Using Digital Terrain Analysis\" (the PVPS paper)".into(),
        differences: vec![
            "Terrain: the shared Puget Sound map, 1025^2 at 160 m (relief 4380 m); the paper's: a 4096^2, 12.5 m DEM south of Luoyang (relief not stated).".into(),
            "Method A is a stand-in (Röttger's d2 roughness), not Zhai 2016's code; method B follows Dong 2017's max - min roughness (docs/papers.md).".into(),
            "Hardware: software Vulkan (lavapipe) on a shared 2-core machine; the paper: OpenGL 4.6 on a GTX 1660Ti. Frame rates compare by ratio only.".into(),
        ],
        commands: Vec::new(),
        load: Vec::new(),
        quick: false,
        sections: vec![table2(&t2, &setting), table3(&t3, &setting)],
    })
}
