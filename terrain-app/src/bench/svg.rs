//! The benchmark report as a hand-written SVG ([`BenchReport::to_svg`]): triangles and CPU
//! milliseconds against the 99th-percentile pixel error, one log-log curve per method.

use std::fmt::Write as _;

use super::record::{BenchReport, RunRecord, RunSummary};
use crate::method::registry::colour;
use crate::methods::LodMethod;

/// Smallest pixel error the log axis shows; smaller ones (full resolution: 0) sit on it.
const PX_FLOOR: f64 = 1e-3;

impl BenchReport {
    /// The methods in run order, without repeats.
    fn methods(&self) -> Vec<LodMethod> {
        let mut v: Vec<LodMethod> = Vec::new();
        for r in &self.runs {
            if !v.contains(&r.method) {
                v.push(r.method);
            }
        }
        v
    }

    /// Two log-log plots per flight: triangles and CPU ms against the median p99 pixel error,
    /// one polyline per method (its sweep points), with a legend.
    pub fn to_svg(&self) -> String {
        let (pw, ph) = (420.0, 300.0);
        let methods = self.methods();
        let legend_h = 24.0;
        let rows = self.flights.len().max(1);
        let (w, h) = (2.0 * pw, rows as f64 * ph + legend_h);
        let mut s = String::new();
        let _ = writeln!(
            s,
            r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" viewBox="0 0 {w} {h}" font-family="sans-serif" font-size="11">"#
        );
        let _ = writeln!(s, r#"<rect width="{w}" height="{h}" fill="white"/>"#);
        for (k, m) in methods.iter().enumerate() {
            let x = 10.0 + k as f64 * 110.0;
            let _ = writeln!(
                s,
                r#"<line x1="{x}" y1="12" x2="{}" y2="12" stroke="{}" stroke-width="2"/><text x="{}" y="16">{}</text>"#,
                x + 20.0,
                colour(*m),
                x + 25.0,
                m.name()
            );
        }
        for (row, f) in self.flights.iter().enumerate() {
            // Runs from the store (`--from-store`) repeat their method's curve: the table has them.
            let runs: Vec<&RunRecord> =
                self.runs.iter().filter(|r| r.flight == f.name && !r.from_store).collect();
            let y0 = legend_h + row as f64 * ph;
            let panels: [(&str, Axis); 2] =
                [("triangles", |m| m.median_triangles), ("CPU ms per frame", |m| m.median_cpu_ms)];
            for (col, (ylabel, yof)) in panels.into_iter().enumerate() {
                let title = format!("{}: {ylabel} vs p99 px ({})", f.name, self.terrain);
                // A run whose every frame missed data has no error to plot (NaN).
                let points: Vec<(LodMethod, f64, f64)> = runs
                    .iter()
                    .filter(|r| !r.summary.median_p99_px.is_nan())
                    .map(|r| (r.method, r.summary.median_p99_px.max(PX_FLOOR), yof(&r.summary)))
                    .collect();
                plot_panel(&mut s, col as f64 * pw, y0, pw, ph, &title, ylabel, &methods, &points);
            }
        }
        s.push_str("</svg>\n");
        s
    }
}

/// A plot's y value of a run.
type Axis = fn(&RunSummary) -> f64;

/// Power-of-ten range covering the positive values of `v`.
pub(super) fn log_range(v: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for x in v.filter(|x| *x > 0.0 && x.is_finite()) {
        lo = lo.min(x);
        hi = hi.max(x);
    }
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    let (a, b) = (lo.log10().floor(), hi.log10().ceil());
    (a, if b > a { b } else { a + 1.0 })
}

/// One log-log panel at `(x0, y0)` of size `w x h`.
#[allow(clippy::too_many_arguments)]
fn plot_panel(
    s: &mut String,
    x0: f64,
    y0: f64,
    w: f64,
    h: f64,
    title: &str,
    ylabel: &str,
    methods: &[LodMethod],
    points: &[(LodMethod, f64, f64)],
) {
    let (l, r, t, b) = (x0 + 60.0, x0 + w - 15.0, y0 + 25.0, y0 + h - 40.0);
    let (xa, xb) = log_range(points.iter().map(|p| p.1));
    let (ya, yb) = log_range(points.iter().map(|p| p.2));
    let px = |x: f64| l + (x.max(1e-300).log10() - xa) / (xb - xa) * (r - l);
    let py = |y: f64| b - (y.max(1e-300).log10() - ya) / (yb - ya) * (b - t);
    let _ = writeln!(
        s,
        r#"<text x="{}" y="{}" font-weight="bold">{}</text>"#,
        l,
        y0 + 15.0,
        esc(title)
    );
    let _ = writeln!(
        s,
        r##"<rect x="{l}" y="{t}" width="{}" height="{}" fill="none" stroke="#999"/>"##,
        r - l,
        b - t
    );
    for e in xa as i32..=xb as i32 {
        let x = px(10f64.powi(e));
        let _ = writeln!(
            s,
            r##"<line x1="{x:.1}" y1="{t}" x2="{x:.1}" y2="{b}" stroke="#eee"/><text x="{x:.1}" y="{}" text-anchor="middle">{}</text>"##,
            b + 14.0,
            tick(e)
        );
    }
    for e in ya as i32..=yb as i32 {
        let y = py(10f64.powi(e));
        let _ = writeln!(
            s,
            r##"<line x1="{l}" y1="{y:.1}" x2="{r}" y2="{y:.1}" stroke="#eee"/><text x="{}" y="{:.1}" text-anchor="end">{}</text>"##,
            l - 4.0,
            y + 4.0,
            tick(e)
        );
    }
    let _ = writeln!(
        s,
        r#"<text x="{}" y="{}" text-anchor="middle">p99 pixel error (median over frames; 0 drawn at {PX_FLOOR})</text>"#,
        (l + r) / 2.0,
        b + 30.0
    );
    let _ = writeln!(
        s,
        r#"<text x="{}" y="{}" text-anchor="middle" transform="rotate(-90 {} {})">{}</text>"#,
        x0 + 14.0,
        (t + b) / 2.0,
        x0 + 14.0,
        (t + b) / 2.0,
        esc(ylabel)
    );
    for m in methods {
        let mut pts: Vec<(f64, f64)> =
            points.iter().filter(|p| p.0 == *m).map(|p| (p.1, p.2)).collect();
        pts.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.total_cmp(&b.1)));
        let c = colour(*m);
        let path: Vec<String> =
            pts.iter().map(|&(x, y)| format!("{:.1},{:.1}", px(x), py(y))).collect();
        let _ = writeln!(
            s,
            r#"<polyline points="{}" fill="none" stroke="{c}" stroke-width="1.5"/>"#,
            path.join(" ")
        );
        for &(x, y) in &pts {
            let _ =
                writeln!(s, r#"<circle cx="{:.1}" cy="{:.1}" r="2.5" fill="{c}"/>"#, px(x), py(y));
        }
    }
}

fn tick(e: i32) -> String {
    if (-3..=5).contains(&e) { format!("{}", 10f64.powi(e)) } else { format!("1e{e}") }
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;")
}
