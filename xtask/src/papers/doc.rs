//! The papers' result documents: tables (ours beside the paper's), verdicts computed from the
//! numbers by a written rule, and sections a run could not produce (with the reason), written
//! as Markdown and JSON (and SVG line charts for figures).

use serde::{Serialize, Serializer};

/// One cell: a number (JSON keeps it as a number; `NaN` is `null`) or text.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Cell {
    /// A number and the decimals Markdown shows.
    Num(f64, usize),
    /// Text.
    Text(String),
}

impl Cell {
    fn to_markdown(&self) -> String {
        match self {
            Cell::Num(v, _) if !v.is_finite() => "n/a".to_string(),
            Cell::Num(v, dp) => thousands(*v, *dp),
            Cell::Text(s) => s.clone(),
        }
    }
}

impl Serialize for Cell {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            Cell::Num(v, _) if v.is_finite() => s.serialize_f64(*v),
            Cell::Num(..) => s.serialize_none(),
            Cell::Text(t) => s.serialize_str(t),
        }
    }
}

/// `v` with `dp` decimals and thousands separated by commas (the papers' style).
fn thousands(v: f64, dp: usize) -> String {
    let s = format!("{:.*}", dp, v.abs());
    let (int, frac) = s.split_once('.').map_or((s.as_str(), ""), |(a, b)| (a, b));
    let mut out = String::new();
    for (k, ch) in int.chars().enumerate() {
        if k > 0 && (int.len() - k) % 3 == 0 {
            out.push(',');
        }
        out.push(ch);
    }
    let sign = if v < 0.0 && s.chars().any(|c| c.is_ascii_digit() && c != '0') { "-" } else { "" };
    if frac.is_empty() { format!("{sign}{out}") } else { format!("{sign}{out}.{frac}") }
}

/// A number cell.
pub(crate) fn num(v: f64, dp: usize) -> Cell {
    Cell::Num(v, dp)
}

/// A text cell.
pub(crate) fn text(s: impl Into<String>) -> Cell {
    Cell::Text(s.into())
}

/// A table: a caption, column names and rows of cells.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub(crate) struct Table {
    /// What the table shows.
    pub(crate) caption: String,
    /// Column names (with units).
    pub(crate) columns: Vec<String>,
    /// The rows.
    pub(crate) rows: Vec<Vec<Cell>>,
}

impl Table {
    /// An empty table with `columns`.
    pub(crate) fn new(caption: impl Into<String>, columns: &[&str]) -> Self {
        Self {
            caption: caption.into(),
            columns: columns.iter().map(|c| c.to_string()).collect(),
            rows: Vec::new(),
        }
    }

    fn to_markdown(&self) -> String {
        let mut s = format!("{}\n\n| {} |\n|", self.caption, self.columns.join(" | "));
        for k in 0..self.columns.len() {
            s += if k == 0 { "---|" } else { "---:|" };
        }
        s.push('\n');
        for row in &self.rows {
            let cells: Vec<String> = row.iter().map(Cell::to_markdown).collect();
            s += &format!("| {} |\n", cells.join(" | "));
        }
        s
    }
}

/// How a claim came out.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub(crate) enum Outcome {
    /// Ours holds the claim to about the paper's degree.
    Reproduced,
    /// Ours holds it by clearly more than the paper's figure.
    Beaten,
    /// Ours goes the paper's way by too little, or not at all.
    NotReproduced,
    /// Ours goes the other way.
    Reversed,
    /// A number was missing (NaN): the run did not produce it.
    NotComputed,
}

impl Outcome {
    fn word(self) -> &'static str {
        match self {
            Outcome::Reproduced => "reproduced",
            Outcome::Beaten => "beaten",
            Outcome::NotReproduced => "not reproduced",
            Outcome::Reversed => "reversed",
            Outcome::NotComputed => "NOT COMPUTED",
        }
    }
}

/// A claim of the paper, its figure, ours, the rule and the outcome the rule gives.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub(crate) struct Verdict {
    /// The claim, in words.
    pub(crate) claim: String,
    /// The paper's figure for it.
    pub(crate) paper: f64,
    /// Ours.
    pub(crate) ours: f64,
    /// The rule that turns the two into the outcome.
    pub(crate) rule: String,
    /// The outcome.
    pub(crate) outcome: Outcome,
    /// Why a claim does not hold here, measured ([`Verdict::because`]); printed under the
    /// verdict.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) why: Option<String>,
}

impl Verdict {
    /// The verdict with `why` (a measured reason) attached when the claim does not hold
    /// (not reproduced or reversed); unchanged otherwise.
    pub(crate) fn because(mut self, why: impl FnOnce() -> String) -> Self {
        if matches!(self.outcome, Outcome::NotReproduced | Outcome::Reversed) {
            self.why = Some(why());
        }
        self
    }
}

/// The rule of [`effect`], in words.
pub(crate) const EFFECT_RULE: &str = "effect = ratio - 1, signed, in the claim's direction; \
reversed: ours against the claim and beyond 2 %; not reproduced: |ours| within 2 %, or below \
0.5 |paper|; beaten: |ours| above 1.5 |paper|, or the claim held where the paper's own numbers \
do not show it; reproduced otherwise";

/// A claimed relative effect (`ratio - 1`, e.g. -0.31 for "31 % fewer triangles") in the
/// direction of the paper's own figure `paper`; ours `ours` ([`EFFECT_RULE`]).
pub(crate) fn effect(claim: impl Into<String>, paper: f64, ours: f64) -> Verdict {
    effect_towards(claim, paper.signum(), paper, ours)
}

/// A claimed relative effect in direction `dir` (-1: ours lower, +1: higher), with the
/// paper's figure `paper` (which may itself go against the claim) and ours ([`EFFECT_RULE`]).
pub(crate) fn effect_towards(claim: impl Into<String>, dir: f64, paper: f64, ours: f64) -> Verdict {
    let along = |x: f64| x * dir.signum();
    let outcome = if !(paper.is_finite() && ours.is_finite() && dir != 0.0) {
        Outcome::NotComputed
    } else if along(ours) < -0.02 {
        Outcome::Reversed
    } else if along(ours) <= 0.02 {
        Outcome::NotReproduced
    } else if along(paper) <= 0.0 || along(ours) > 1.5 * along(paper) {
        Outcome::Beaten
    } else if along(ours) < 0.5 * along(paper) {
        Outcome::NotReproduced
    } else {
        Outcome::Reproduced
    };
    Verdict { claim: claim.into(), paper, ours, rule: EFFECT_RULE.to_string(), outcome, why: None }
}

/// A hypothesis's prediction: `ours` at least (or, with `at_least` false, at most) `bound`
/// (kept as the "paper" figure): reproduced when it is, not reproduced otherwise.
pub(crate) fn prediction(
    claim: impl Into<String>,
    bound: f64,
    ours: f64,
    at_least: bool,
) -> Verdict {
    let holds = if at_least { ours >= bound } else { ours <= bound };
    let outcome = if !(bound.is_finite() && ours.is_finite()) {
        Outcome::NotComputed
    } else if holds {
        Outcome::Reproduced
    } else {
        Outcome::NotReproduced
    };
    let rule = format!(
        "a prediction (its bound in place of the paper's figure): reproduced when ours is at {} \
         the bound, not reproduced otherwise",
        if at_least { "least" } else { "most" }
    );
    Verdict { claim: claim.into(), paper: bound, ours, rule, outcome, why: None }
}

/// A figure where lower is better (a share of data loaded late, a storage ratio): beaten below
/// `paper / 1.5` (or `paper - tol` when `tol` is given, for ratios near 1), reproduced up to
/// `paper x 1.5` (or `+ tol`), reversed at or above `worst` (the claim's opposite: e.g. the
/// share without the technique), not reproduced between.
pub(crate) fn lower_is_better(
    claim: impl Into<String>,
    paper: f64,
    ours: f64,
    tol: Option<f64>,
    worst: f64,
) -> Verdict {
    let (good, ok, rule) = match tol {
        Some(t) => (
            paper - t,
            paper + t,
            format!(
                "lower is better: beaten below paper - {t}, reproduced within paper +- {t}, \
                 reversed at or above {worst:.3}, not reproduced between"
            ),
        ),
        None => (
            paper / 1.5,
            paper * 1.5,
            format!(
                "lower is better: beaten below paper / 1.5, reproduced up to paper x 1.5, \
                 reversed at or above {worst:.3}, not reproduced between"
            ),
        ),
    };
    let outcome = if !(paper.is_finite() && ours.is_finite()) {
        Outcome::NotComputed
    } else if ours >= worst {
        Outcome::Reversed
    } else if ours < good {
        Outcome::Beaten
    } else if ours <= ok {
        Outcome::Reproduced
    } else {
        Outcome::NotReproduced
    };
    Verdict { claim: claim.into(), paper, ours, rule, outcome, why: None }
}

/// A line chart: one polyline per series over a shared x axis.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub(crate) struct Figure {
    /// File name (under the paper's folder), `.svg`.
    pub(crate) file: String,
    /// Title.
    pub(crate) title: String,
    /// X axis label.
    pub(crate) x_label: String,
    /// Y axis label.
    pub(crate) y_label: String,
    /// Series: a name and its points.
    pub(crate) series: Vec<(String, Vec<(f64, f64)>)>,
}

impl Figure {
    /// The chart as SVG (hand-written; linear axes from 0).
    pub(crate) fn to_svg(&self) -> String {
        let (w, h, l, r, t, b) = (640.0, 360.0, 70.0, 160.0, 40.0, 50.0);
        let pts = self.series.iter().flat_map(|(_, p)| p.iter()).filter(|p| p.1.is_finite());
        let (mut xmax, mut ymax) = (0.0f64, 0.0f64);
        for &(x, y) in pts {
            xmax = xmax.max(x);
            ymax = ymax.max(y);
        }
        let (xmax, ymax) =
            (if xmax > 0.0 { xmax } else { 1.0 }, if ymax > 0.0 { ymax } else { 1.0 });
        let px = |x: f64| l + x / xmax * (w - l - r);
        let py = |y: f64| h - b - y / ymax * (h - t - b);
        let colours = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b"];
        let mut s = format!(
            "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"{h}\" \
             font-family=\"sans-serif\" font-size=\"12\">\n<rect width=\"100%\" height=\"100%\" \
             fill=\"white\"/>\n<text x=\"{}\" y=\"22\" text-anchor=\"middle\" \
             font-size=\"14\">{}</text>\n",
            w / 2.0,
            escape(&self.title)
        );
        s += &format!(
            "<line x1=\"{l}\" y1=\"{}\" x2=\"{}\" y2=\"{}\" stroke=\"black\"/>\n<line x1=\"{l}\" \
             y1=\"{t}\" x2=\"{l}\" y2=\"{}\" stroke=\"black\"/>\n",
            h - b,
            w - r,
            h - b,
            h - b
        );
        for k in 0..=4 {
            let (fx, fy) = (xmax * k as f64 / 4.0, ymax * k as f64 / 4.0);
            s += &format!(
                "<text x=\"{:.1}\" y=\"{}\" text-anchor=\"middle\">{}</text>\n<text x=\"{}\" \
                 y=\"{:.1}\" text-anchor=\"end\">{}</text>\n",
                px(fx),
                h - b + 16.0,
                short(fx),
                l - 6.0,
                py(fy) + 4.0,
                short(fy)
            );
        }
        s += &format!(
            "<text x=\"{:.1}\" y=\"{}\" text-anchor=\"middle\">{}</text>\n<text x=\"16\" \
             y=\"{:.1}\" text-anchor=\"middle\" transform=\"rotate(-90 16 {:.1})\">{}</text>\n",
            (l + w - r) / 2.0,
            h - 12.0,
            escape(&self.x_label),
            (t + h - b) / 2.0,
            (t + h - b) / 2.0,
            escape(&self.y_label)
        );
        for (k, (name, points)) in self.series.iter().enumerate() {
            let c = colours[k % colours.len()];
            let path: Vec<String> = points
                .iter()
                .filter(|p| p.1.is_finite())
                .map(|&(x, y)| format!("{:.1},{:.1}", px(x), py(y)))
                .collect();
            s += &format!(
                "<polyline fill=\"none\" stroke=\"{c}\" stroke-width=\"1.5\" points=\"{}\"/>\n",
                path.join(" ")
            );
            let ly = t + 16.0 * k as f64;
            s += &format!(
                "<line x1=\"{}\" y1=\"{ly}\" x2=\"{}\" y2=\"{ly}\" stroke=\"{c}\" \
                 stroke-width=\"2\"/><text x=\"{}\" y=\"{}\">{}</text>\n",
                w - r + 10.0,
                w - r + 30.0,
                w - r + 34.0,
                ly + 4.0,
                escape(name)
            );
        }
        s + "</svg>\n"
    }
}

fn short(v: f64) -> String {
    if v >= 100.0 { format!("{v:.0}") } else { format!("{v:.2}") }
}

fn escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;")
}

/// One result table (or figure) of a paper: produced (ours, the paper's, verdicts) or not
/// (with the reason).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub(crate) struct Section {
    /// The paper's name for it ("Table 2").
    pub(crate) id: String,
    /// What it shows.
    pub(crate) title: String,
    /// How ours was produced and how our setting differs from the paper's.
    pub(crate) setup: Vec<String>,
    /// Our tables in the paper's layout.
    pub(crate) ours: Vec<Table>,
    /// The paper's own numbers for the same rows.
    pub(crate) paper: Option<Table>,
    /// One verdict per claim.
    pub(crate) verdicts: Vec<Verdict>,
    /// Figures (SVG files beside the document).
    pub(crate) figures: Vec<Figure>,
    /// Why the section is not produced yet; `None` when it is.
    pub(crate) not_produced: Option<String>,
}

impl Section {
    /// A produced section, to be filled.
    pub(crate) fn new(id: &str, title: &str) -> Self {
        Self {
            id: id.to_string(),
            title: title.to_string(),
            setup: Vec::new(),
            ours: Vec::new(),
            paper: None,
            verdicts: Vec::new(),
            figures: Vec::new(),
            not_produced: None,
        }
    }

    /// A section not produced yet, with the reason.
    #[allow(dead_code)] // every section is produced at present; kept for those that are not
    pub(crate) fn missing(id: &str, title: &str, reason: &str) -> Self {
        Self { not_produced: Some(reason.to_string()), ..Self::new(id, title) }
    }

    /// What is wrong with a produced section: no table, no verdict, a verdict not computed.
    pub(crate) fn problems(&self) -> Vec<String> {
        if self.not_produced.is_some() {
            return Vec::new();
        }
        let mut p = Vec::new();
        if self.ours.iter().all(|t| t.rows.is_empty()) {
            p.push(format!("{}: no table rows", self.id));
        }
        if self.verdicts.is_empty() {
            p.push(format!("{}: no verdict", self.id));
        }
        for v in self.verdicts.iter().filter(|v| v.outcome == Outcome::NotComputed) {
            p.push(format!("{}: verdict not computed: {}", self.id, v.claim));
        }
        p
    }
}

/// One paper's document.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub(crate) struct PaperDoc {
    /// The short key (`ooc`, `pvps`, ...).
    pub(crate) key: String,
    /// The paper.
    pub(crate) title: String,
    /// How our setting differs from the paper's overall (terrain, scale, hardware).
    pub(crate) differences: Vec<String>,
    /// The `terrain` commands run, in order.
    pub(crate) commands: Vec<String>,
    /// Machine load (`/proc/loadavg`) at the start and the end, and the wall time.
    pub(crate) load: Vec<String>,
    /// Whether these are `--quick` figures.
    pub(crate) quick: bool,
    /// The sections, in the paper's order.
    pub(crate) sections: Vec<Section>,
}

impl PaperDoc {
    /// The Markdown document.
    pub(crate) fn to_markdown(&self) -> String {
        let mut s = format!(
            "# {}: results regenerated\n\nGenerated by `cargo xtask papers --paper {}{}`; do not \
             edit (the JSON beside it has the same numbers). Verdicts are computed from the \
             numbers by the rule printed under each.\n\n",
            self.title,
            self.key,
            if self.quick { " --quick" } else { "" }
        );
        if self.quick {
            s += "**Quick run**: few frames and small settings; it checks that every table and \
                  verdict is computed, not that the claims hold.\n\n";
        }
        s += "## Our setting against the paper's\n\n";
        for d in &self.differences {
            s += &format!("- {d}\n");
        }
        s += "\n## Commands and machine load\n\n```sh\n";
        for c in &self.commands {
            s += &format!("{c}\n");
        }
        s += "```\n\n";
        for l in &self.load {
            s += &format!("- {l}\n");
        }
        for sec in &self.sections {
            s += &format!("\n## {}: {}\n\n", sec.id, sec.title);
            if let Some(reason) = &sec.not_produced {
                s += &format!("**Not produced yet.** {reason}\n");
                if let Some(p) = &sec.paper {
                    s += &format!("\n**The paper's.** {}", p.to_markdown());
                }
                continue;
            }
            for line in &sec.setup {
                s += &format!("- {line}\n");
            }
            for t in &sec.ours {
                s += &format!("\n**Ours.** {}", t.to_markdown());
            }
            if let Some(p) = &sec.paper {
                s += &format!("\n**The paper's.** {}", p.to_markdown());
            }
            for f in &sec.figures {
                s += &format!("\n![{}]({})\n", f.title, f.file);
            }
            if !sec.verdicts.is_empty() {
                s += "\n**Verdicts.**\n\n";
                let mut rules: Vec<&str> = Vec::new();
                for v in &sec.verdicts {
                    s += &format!(
                        "- **{}**: {} (paper {}, ours {})\n",
                        v.outcome.word(),
                        v.claim,
                        fig(v.paper),
                        fig(v.ours)
                    );
                    if let Some(why) = &v.why {
                        s += &format!("  - why: {why}\n");
                    }
                    if !rules.contains(&v.rule.as_str()) {
                        rules.push(&v.rule);
                    }
                }
                s += "\nRules: ";
                s += &rules.join("; ");
                s += ".\n";
            }
        }
        s
    }
}

fn fig(v: f64) -> String {
    if !v.is_finite() {
        "n/a".to_string()
    } else if v.abs() >= 100.0 {
        format!("{v:.0}")
    } else {
        format!("{v:.3}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A quick run's document of `sections`, with no differences, commands or load.
    fn quick_doc(sections: Vec<Section>) -> PaperDoc {
        PaperDoc {
            key: "k".into(),
            title: "T".into(),
            differences: vec![],
            commands: vec![],
            load: vec![],
            quick: true,
            sections,
        }
    }

    #[test]
    fn effects_are_judged_by_sign_and_size() {
        // The paper: 30 % fewer.
        assert_eq!(effect("c", -0.3, -0.31).outcome, Outcome::Reproduced);
        assert_eq!(effect("c", -0.3, -0.6).outcome, Outcome::Beaten);
        assert_eq!(effect("c", -0.3, -0.1).outcome, Outcome::NotReproduced);
        assert_eq!(effect("c", -0.3, 0.01).outcome, Outcome::NotReproduced);
        assert_eq!(effect("c", -0.3, 0.2).outcome, Outcome::Reversed);
        assert_eq!(effect("c", -0.3, 0.05).outcome, Outcome::Reversed);
        assert_eq!(effect("c", -0.3, f64::NAN).outcome, Outcome::NotComputed);
        // The claim says lower; the paper's own figure went up: ours lower beats it.
        assert_eq!(effect_towards("c", -1.0, 0.06, -0.2).outcome, Outcome::Beaten);
        assert_eq!(effect_towards("c", -1.0, 0.06, 0.5).outcome, Outcome::Reversed);
        assert_eq!(prediction("c", 0.9, 0.95, true).outcome, Outcome::Reproduced);
        assert_eq!(prediction("c", 0.5, 0.95, false).outcome, Outcome::NotReproduced);
    }

    #[test]
    fn lower_is_better_has_four_outcomes() {
        let v = |ours| lower_is_better("c", 0.1, ours, None, 1.0).outcome;
        assert_eq!(v(0.01), Outcome::Beaten);
        assert_eq!(v(0.12), Outcome::Reproduced);
        assert_eq!(v(0.5), Outcome::NotReproduced);
        assert_eq!(v(1.0), Outcome::Reversed);
        let t = |ours| lower_is_better("c", 1.08, ours, Some(0.05), 2.0).outcome;
        assert_eq!(t(0.7), Outcome::Beaten);
        assert_eq!(t(1.1), Outcome::Reproduced);
        assert_eq!(t(1.5), Outcome::NotReproduced);
    }

    #[test]
    fn a_reason_is_attached_only_where_a_claim_does_not_hold() {
        let why = || "measured".to_string();
        assert_eq!(effect("c", -0.3, -0.3).because(why).why, None);
        assert_eq!(effect("c", -0.3, 0.0).because(why).why.as_deref(), Some("measured"));
        assert_eq!(effect("c", -0.3, 0.5).because(why).why.as_deref(), Some("measured"));
        let mut s = Section::new("Table 1", "t");
        let mut t = Table::new("cap", &["a"]);
        t.rows.push(vec![text("x")]);
        s.ours.push(t);
        s.verdicts.push(effect("fewer", -0.3, 0.0).because(why));
        let doc = quick_doc(vec![s]);
        assert!(doc.to_markdown().contains("ours 0.000)\n  - why: measured\n"));
    }

    #[test]
    fn documents_flag_missing_numbers_and_write_every_part() {
        let mut s = Section::new("Table 1", "t");
        assert_eq!(s.problems().len(), 2);
        let mut t = Table::new("cap", &["a", "b"]);
        t.rows.push(vec![text("x"), num(1234567.891, 1)]);
        s.ours.push(t);
        s.verdicts.push(effect("fewer", -0.3, f64::NAN));
        assert_eq!(s.problems(), vec!["Table 1: verdict not computed: fewer".to_string()]);
        s.verdicts[0] = effect("fewer", -0.3, -0.3);
        assert!(s.problems().is_empty());
        let gap = Section::missing("Table 2", "u", "no path");
        assert!(gap.problems().is_empty());
        let doc = quick_doc(vec![s, gap]);
        let md = doc.to_markdown();
        assert!(md.contains("| x | 1,234,567.9 |"), "{md}");
        assert!(md.contains("**reproduced**: fewer (paper -0.300, ours -0.300)"), "{md}");
        assert!(md.contains("**Not produced yet.** no path"));
        let json = serde_json::to_string(&doc).unwrap();
        assert!(json.contains("[\"x\",1234567.891]"), "{json}");
        assert_eq!(thousands(-0.0001, 2), "0.00");
        assert_eq!(thousands(-1234.5, 1), "-1,234.5");
    }
}
