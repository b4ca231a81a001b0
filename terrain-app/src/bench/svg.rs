//! The benchmark report as a hand-written SVG ([`BenchReport::to_svg`]): triangles and CPU
//! milliseconds against the 99th-percentile pixel error, one log-log curve per method, each
//! method with its own colour and marker ([`crate::method::registry::colour`], [`marker`]).
//!
//! Every label is laid out inside the image: the legend wraps onto as many rows as it needs,
//! and a title too wide for its panel is set smaller (then shortened). Text widths are
//! estimated from the character count ([`text_width`], a generous average advance of sans-serif
//! faces), since the SVG is written without a font; the tests parse the SVG and check every
//! text element's estimated extent against the viewBox.

use std::fmt::Write as _;

use super::record::{BenchReport, RunRecord, RunSummary};
use crate::method::registry::{Marker, colour, marker};
use crate::methods::LodMethod;

/// Smallest pixel error the log axis shows; smaller ones (full resolution: 0) sit on it.
const PX_FLOOR: f64 = 1e-3;

/// Estimated average advance of a character, in ems: generous for sans-serif faces (DejaVu
/// Sans, the widest common default, averages about 0.55 em on lower case and 0.64 em on
/// digits; bold about 10 % more).
pub(super) const CHAR_EM: f64 = 0.62;
/// The same for bold text.
pub(super) const BOLD_CHAR_EM: f64 = 0.68;

/// Base font size of the plot, px.
const FONT: f64 = 11.0;
/// Width and height of one panel, px.
const PANEL: (f64, f64) = (460.0, 320.0);
/// Height of a legend row, px.
const LEGEND_ROW: f64 = 18.0;
/// Margin around the legend and the title, px.
const MARGIN: f64 = 10.0;

/// Estimated width of `text` at `size` px (bold or not).
pub(super) fn text_width(text: &str, size: f64, bold: bool) -> f64 {
    let em = if bold { BOLD_CHAR_EM } else { CHAR_EM };
    text.chars().count() as f64 * size * em
}

/// `text` fitted into `width` px: at `size` if it fits, else at a smaller size down to 8 px,
/// else shortened with an ellipsis at 8 px. Returns the text and its size.
fn fit(text: &str, size: f64, bold: bool, width: f64) -> (String, f64) {
    let mut s = size;
    while s > 8.0 && text_width(text, s, bold) > width {
        s -= 0.5;
    }
    if text_width(text, s, bold) <= width {
        return (text.to_string(), s);
    }
    let keep = ((width / (s * if bold { BOLD_CHAR_EM } else { CHAR_EM })) as usize).max(2) - 1;
    (format!("{}…", text.chars().take(keep).collect::<String>()), s)
}

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
    /// one polyline per method (its sweep points) with its markers, under a title and a legend.
    pub fn to_svg(&self) -> String {
        let (pw, ph) = PANEL;
        let methods = self.methods();
        let w = 2.0 * pw;
        // The legend's entries: a line with the marker, then the name; wrapped into rows.
        let mut entries: Vec<(LodMethod, f64, f64)> = Vec::new();
        let (mut x, mut row) = (MARGIN, 0usize);
        for &m in &methods {
            let ew = 30.0 + text_width(m.name(), FONT, false);
            if x > MARGIN && x + ew > w - MARGIN {
                (x, row) = (MARGIN, row + 1);
            }
            entries.push((m, x, row as f64));
            x += ew + 16.0;
        }
        let title_h = 24.0;
        let legend_h = if methods.is_empty() { 0.0 } else { (row + 1) as f64 * LEGEND_ROW };
        let top = title_h + legend_h + 6.0;
        let rows = self.flights.len().max(1);
        let h = top + rows as f64 * ph;
        let mut s = String::new();
        let _ = writeln!(
            s,
            r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" viewBox="0 0 {w} {h}" font-family="sans-serif" font-size="{FONT}">"#
        );
        let _ = writeln!(s, r#"<rect width="{w}" height="{h}" fill="white"/>"#);
        let title = format!(
            "{} ({} x {}): cost against p99 pixel error, one curve per method",
            self.terrain, self.grid[0], self.grid[1]
        );
        let (title, size) = fit(&title, 13.0, true, w - 2.0 * MARGIN);
        let _ = writeln!(
            s,
            r#"<text x="{MARGIN}" y="17" font-size="{size}" font-weight="bold">{}</text>"#,
            esc(&title)
        );
        for &(m, x, row) in &entries {
            let y = title_h + row * LEGEND_ROW + 9.0;
            let c = colour(m);
            let _ = writeln!(
                s,
                r#"<line x1="{x}" y1="{y}" x2="{}" y2="{y}" stroke="{c}" stroke-width="2"/>"#,
                x + 24.0
            );
            draw_marker(&mut s, marker(m), c, x + 12.0, y);
            let _ = writeln!(s, r#"<text x="{}" y="{}">{}</text>"#, x + 30.0, y + 4.0, m.name());
        }
        for (row, f) in self.flights.iter().enumerate() {
            // Runs from the store (`--from-store`) repeat their method's curve from memory (the
            // table has them); a method run from the store only is drawn from those.
            let runs: Vec<&RunRecord> =
                self.runs
                    .iter()
                    .filter(|r| r.flight == f.name)
                    .filter(|r| {
                        !r.from_store
                            || !self.runs.iter().any(|o| {
                                o.flight == f.name && o.method == r.method && !o.from_store
                            })
                    })
                    .collect();
            let y0 = top + row as f64 * ph;
            let panels: [(&str, Axis); 2] =
                [("triangles", |m| m.median_triangles), ("CPU ms per frame", |m| m.median_cpu_ms)];
            for (col, (ylabel, yof)) in panels.into_iter().enumerate() {
                let title = format!("{}: {ylabel}", f.name);
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

/// `shape` in colour `c` centred on `(x, y)`.
fn draw_marker(s: &mut String, shape: Marker, c: &str, x: f64, y: f64) {
    let r = 3.5;
    let poly = |pts: &[(f64, f64)]| {
        pts.iter().map(|(a, b)| format!("{:.1},{:.1}", x + a, y + b)).collect::<Vec<_>>().join(" ")
    };
    let _ = match shape {
        Marker::Circle => writeln!(s, r#"<circle cx="{x:.1}" cy="{y:.1}" r="{r}" fill="{c}"/>"#),
        Marker::Ring => writeln!(
            s,
            r#"<circle cx="{x:.1}" cy="{y:.1}" r="{r}" fill="white" stroke="{c}" stroke-width="1.5"/>"#
        ),
        Marker::Square => writeln!(
            s,
            r#"<rect x="{:.1}" y="{:.1}" width="{}" height="{}" fill="{c}"/>"#,
            x - r,
            y - r,
            2.0 * r,
            2.0 * r
        ),
        Marker::Triangle => writeln!(
            s,
            r#"<polygon points="{}" fill="{c}"/>"#,
            poly(&[(0.0, -r - 0.5), (r + 0.5, r), (-r - 0.5, r)])
        ),
        Marker::TriangleDown => writeln!(
            s,
            r#"<polygon points="{}" fill="{c}"/>"#,
            poly(&[(0.0, r + 0.5), (r + 0.5, -r), (-r - 0.5, -r)])
        ),
        Marker::Diamond => writeln!(
            s,
            r#"<polygon points="{}" fill="{c}"/>"#,
            poly(&[(0.0, -r - 1.0), (r + 1.0, 0.0), (0.0, r + 1.0), (-r - 1.0, 0.0)])
        ),
    };
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
    // The title starts over the y axis' labels and ends at the panel's right edge.
    let (title, size) = fit(title, 12.0, true, x0 + w - 8.0 - (x0 + 8.0));
    let _ = writeln!(
        s,
        r#"<text x="{}" y="{}" font-size="{size}" font-weight="bold">{}</text>"#,
        x0 + 8.0,
        y0 + 15.0,
        esc(&title)
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
    let (xlabel, size) = fit(
        &format!("p99 pixel error (median over frames; 0 drawn at {PX_FLOOR})"),
        FONT,
        false,
        w - 16.0,
    );
    let _ = writeln!(
        s,
        r#"<text x="{}" y="{}" text-anchor="middle" font-size="{size}">{}</text>"#,
        (l + r) / 2.0,
        b + 30.0,
        esc(&xlabel)
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
            draw_marker(s, marker(*m), c, px(x), py(y));
        }
    }
}

fn tick(e: i32) -> String {
    if (-3..=5).contains(&e) { format!("{}", 10f64.powi(e)) } else { format!("1e{e}") }
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;")
}

#[cfg(test)]
mod tests {
    use terrain_core::measure::FrameErrors;

    use super::*;
    use crate::bench::{FlightInfo, FrameRecord};

    /// A report of every method over two flights with long names, three sweep points each.
    fn report() -> BenchReport {
        let flights = ["a_flight_with_a_rather_long_descriptive_name_2026", "short"];
        let mut runs = Vec::new();
        for f in flights {
            for (k, &method) in LodMethod::ALL.iter().enumerate() {
                for step in 0..3 {
                    let p99 = 0.2 * (1.0 + k as f64) * 2f64.powi(step);
                    let frame = FrameRecord {
                        triangles: 100_000 >> step,
                        cpu_ms: 1.0 + k as f64,
                        errors: FrameErrors { p99_px: p99, ..FrameErrors::default() },
                        ..FrameRecord::default()
                    };
                    runs.push(RunRecord {
                        flight: f.into(),
                        method,
                        from_store: false,
                        parameter: "p",
                        value: f64::from(step),
                        summary: RunSummary::new(std::slice::from_ref(&frame)),
                        frames: vec![frame],
                        stream: None,
                    });
                }
            }
        }
        BenchReport {
            terrain: "a synthetic terrain with a long name for the title".into(),
            grid: [8193, 8193],
            adapter: None,
            timing_notes: Vec::new(),
            leaf_cells: 16,
            measure_viewport: [1280, 720],
            render_size: None,
            flights: flights
                .iter()
                .map(|f| FlightInfo {
                    name: f.to_string(),
                    total_frames: 1,
                    frames: vec![0],
                    warnings: Vec::new(),
                })
                .collect(),
            runs,
        }
    }

    /// An attribute of an SVG tag, parsed.
    fn attr(tag: &str, name: &str) -> Option<String> {
        let key = format!(" {name}=\"");
        let at = tag.find(&key)? + key.len();
        Some(tag[at..].split('"').next()?.to_string())
    }

    /// Every `<text>` of `svg`: its estimated box `[x0, y0, x1, y1]` and its text.
    fn text_boxes(svg: &str) -> Vec<([f64; 4], String)> {
        let num = |t: &str, n: &str| attr(t, n).map(|v| v.parse::<f64>().unwrap());
        let root = &svg[..svg.find('>').unwrap()];
        let base = num(root, "font-size").unwrap();
        let mut out = Vec::new();
        for piece in svg.split("<text").skip(1) {
            let (tag, rest) = piece.split_once('>').unwrap();
            let text = rest.split("</text>").next().unwrap();
            let text = text.replace("&lt;", "<").replace("&gt;", ">").replace("&amp;", "&");
            let size = num(tag, "font-size").unwrap_or(base);
            let width = text_width(&text, size, attr(tag, "font-weight").is_some());
            let (x, y) = (num(tag, "x").unwrap(), num(tag, "y").unwrap());
            let (a, b) = match attr(tag, "text-anchor").as_deref() {
                Some("middle") => (-width / 2.0, width / 2.0),
                Some("end") => (-width, 0.0),
                _ => (0.0, width),
            };
            // Ascent about the font size above the baseline, descent a quarter below.
            let bx = match attr(tag, "transform") {
                // rotate(-90 x y) about the anchor: the text runs upwards.
                Some(t) if t.starts_with("rotate(-90") => [x - size, y - b, x + size / 4.0, y - a],
                Some(t) => panic!("unexpected transform {t}"),
                None => [x + a, y - size, x + b, y + size / 4.0],
            };
            out.push((bx, text));
        }
        out
    }

    #[test]
    fn every_label_lies_inside_the_image() {
        let svg = report().to_svg();
        let root = &svg[..svg.find('>').unwrap()];
        let vb: Vec<f64> =
            attr(root, "viewBox").unwrap().split(' ').map(|v| v.parse().unwrap()).collect();
        let boxes = text_boxes(&svg);
        // Every method's name is in the legend, and both panel titles of both flights.
        for m in LodMethod::ALL {
            assert!(boxes.iter().any(|(_, t)| t == m.name()), "{} has no label", m.name());
        }
        assert_eq!(boxes.iter().filter(|(_, t)| t.ends_with(": triangles")).count(), 2);
        assert!(boxes.iter().any(|(_, t)| t == "short: CPU ms per frame"));
        for (bx, text) in &boxes {
            assert!(
                bx[0] >= vb[0]
                    && bx[1] >= vb[1]
                    && bx[2] <= vb[0] + vb[2]
                    && bx[3] <= vb[1] + vb[3],
                "`{text}` at {bx:?} leaves the viewBox {vb:?}"
            );
        }
    }

    /// A panel's title stays within its own panel (half the width), not only the image.
    #[test]
    fn panel_titles_fit_their_panel() {
        let svg = report().to_svg();
        let half = PANEL.0;
        for (bx, text) in text_boxes(&svg) {
            if text.contains(": triangles") || text.contains("…") && bx[0] < half {
                assert!(bx[2] <= half, "`{text}` runs into the next panel: {bx:?}");
            }
        }
    }

    /// A text too long for its room is set smaller, then shortened; one that fits is kept.
    #[test]
    fn fit_shrinks_then_shortens() {
        assert_eq!(fit("abc", 12.0, true, 100.0), ("abc".to_string(), 12.0));
        let long = "x".repeat(40);
        let (t, size) = fit(&long, 12.0, false, 200.0);
        assert_eq!(t, long);
        assert!(size < 12.0 && text_width(&t, size, false) <= 200.0, "{size}");
        let (t, size) = fit(&"y".repeat(400), 12.0, true, 200.0);
        assert!(t.ends_with('…') && size == 8.0 && text_width(&t, size, true) <= 200.0, "{t}");
    }

    #[test]
    fn no_two_methods_share_a_colour_and_marker() {
        let pairs: Vec<_> = LodMethod::ALL.iter().map(|&m| (colour(m), marker(m))).collect();
        for (i, a) in pairs.iter().enumerate() {
            for (j, b) in pairs.iter().enumerate().skip(i + 1) {
                assert_ne!(a, b, "{:?} and {:?}", LodMethod::ALL[i], LodMethod::ALL[j]);
            }
        }
        // The colours alone are distinct too (a marker is small).
        let mut colours: Vec<_> = pairs.iter().map(|p| p.0).collect();
        colours.sort_unstable();
        colours.dedup();
        assert_eq!(colours.len(), LodMethod::ALL.len());
    }

    /// A method run from the store only (the demo) is plotted; one also run from memory is
    /// plotted once.
    #[test]
    fn runs_from_the_store_only_are_plotted() {
        let mut r = report();
        r.runs.retain(|x| x.method == LodMethod::PvpsC && x.flight == "short");
        r.flights.retain(|f| f.name == "short");
        let from_memory = r.to_svg().matches("<circle").count();
        assert!(from_memory > 0);
        for x in &mut r.runs {
            x.from_store = true;
        }
        assert_eq!(r.to_svg().matches("<circle").count(), from_memory);
        let mut both = r.clone();
        both.runs.extend(r.runs.iter().cloned().map(|mut x| {
            x.from_store = false;
            x
        }));
        assert_eq!(both.to_svg().matches("<circle").count(), from_memory);
    }
}
