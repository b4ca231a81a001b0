//! The benchmark report as Markdown ([`BenchReport::to_markdown`]): the set-up, the timing
//! notes, a table per flight, geomorph's vertex jumps and the out-of-core streaming columns.

use std::fmt::Write as _;

use super::record::{BenchReport, RunRecord, median};
use crate::ooc::StreamRecord;

fn opt4(x: Option<f64>) -> String {
    x.map(|x| format!("{x:.4}")).unwrap_or_else(|| "n/a".to_string())
}

/// `x` with `digits` decimals, `n/a` for NaN (an error figure of a run whose every frame
/// missed data).
fn num(x: f64, digits: usize) -> String {
    if x.is_nan() { "n/a".to_string() } else { format!("{x:.digits$}") }
}

/// The frames missing data: `0`, or `k of n (not scored)`.
fn missing(k: usize, n: usize) -> String {
    if k == 0 { "0".to_string() } else { format!("{k} of {n} (not scored)") }
}

fn opt(x: Option<f64>) -> String {
    x.map(|x| format!("{x:.2}")).unwrap_or_else(|| "n/a".to_string())
}

impl BenchReport {
    /// A Markdown report: the set-up, the timing notes, a table per flight.
    pub fn to_markdown(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(s, "# Benchmark: {}\n", self.terrain);
        let _ = writeln!(
            s,
            "- grid {} x {}, leaf patches of {} cells",
            self.grid[0], self.grid[1], self.leaf_cells
        );
        let _ =
            writeln!(s, "- adapter: {}", self.adapter.as_deref().unwrap_or("none (no rendering)"));
        if let Some([w, h]) = self.render_size {
            let _ = writeln!(s, "- rendered at {w} x {h}");
        }
        for n in &self.timing_notes {
            let _ = writeln!(s, "- {n}");
        }
        for f in &self.flights {
            let _ = writeln!(
                s,
                "\n## Flight `{}` ({} of {} frames)\n",
                f.name,
                f.frames.len(),
                f.total_frames
            );
            for w in &f.warnings {
                let _ = writeln!(s, "> warning: {w}\n");
            }
            s.push_str(
                "| method | parameter | triangles | patches | selection ms | CPU ms | frame ms | GPU ms | \
                 p99 px (median / max) | max px | RMSE m | popping RMS m | RMSE change m | \
                 height jump m (median / max) | false culls | frames missing data |\n\
                 |---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
            );
            for r in self.runs.iter().filter(|r| r.flight == f.name) {
                let m = &r.summary;
                let _ = writeln!(
                    s,
                    "| {} | {} = {} | {:.0} | {:.0} | {:.3} | {:.2} | {:.2} | {} | {} / {} | {} | {} | {} | {} | {} / {} | {} | {} |",
                    r.label(),
                    r.parameter,
                    r.value,
                    m.median_triangles,
                    m.median_patches,
                    m.median_selection_ms,
                    m.median_cpu_ms,
                    m.median_frame_ms,
                    opt(m.median_gpu_ms),
                    num(m.median_p99_px, 3),
                    num(m.max_p99_px, 3),
                    num(m.max_px, 3),
                    num(m.median_rmse_m, 3),
                    num(m.median_popping_rms_m, 4),
                    num(m.median_rmse_change_m, 4),
                    num(m.median_max_jump_m, 3),
                    num(m.max_popping_m, 3),
                    if m.frames_missing_data == m.frames && m.frames > 0 {
                        "n/a".to_string()
                    } else {
                        m.false_culls.to_string()
                    },
                    missing(m.frames_missing_data, m.frames)
                );
            }
        }
        let jumps: Vec<&RunRecord> =
            self.runs.iter().filter(|r| r.summary.max_vertex_jump_m.is_some()).collect();
        if !jumps.is_empty() {
            s.push_str(
                "\n## Geomorph: largest per-vertex height jump between consecutive flight frames\n\n\
                 | flight | tau px | with tweening m | tweening off m |\n|---|---:|---:|---:|\n",
            );
            for r in jumps {
                let _ = writeln!(
                    s,
                    "| {} | {} | {} | {} |",
                    r.flight,
                    r.value,
                    opt4(r.summary.max_vertex_jump_m),
                    opt4(r.summary.max_vertex_jump_no_morph_m)
                );
            }
        }
        let ooc: Vec<&RunRecord> =
            self.runs.iter().filter(|r| r.frames.iter().any(|f| f.stream.is_some())).collect();
        if !ooc.is_empty() {
            s.push_str(
                "\n## Out-of-core streaming (the paper's Table 3 columns)\n\n\
                 | flight | tau | needed MiB (median) | synchronous MiB (sum) | sync loads after frame 1 | \
                 prefetched MiB (sum) | I/O ms (median / max) | cache hits | evictions | \
                 peak resident MiB | budget MiB | max queue |\n\
                 |---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
            );
            for r in &ooc {
                let st: Vec<&StreamRecord> =
                    r.frames.iter().filter_map(|f| f.stream.as_ref()).collect();
                let sum = |f: &dyn Fn(&StreamRecord) -> f64| st.iter().map(|x| f(x)).sum::<f64>();
                let max =
                    |f: &dyn Fn(&StreamRecord) -> f64| st.iter().map(|x| f(x)).fold(0.0, f64::max);
                let _ = writeln!(
                    s,
                    "| {} | {} | {:.3} | {:.3} | {} | {:.3} | {:.2} / {:.2} | {} | {} | {:.2} | {:.0} | {} |",
                    r.flight,
                    r.value,
                    median(st.iter().map(|x| x.needed_mib).collect()),
                    sum(&|x| x.sync_mib),
                    st.iter().skip(1).map(|x| x.sync_loads).sum::<usize>(),
                    sum(&|x| x.prefetched_mib),
                    median(st.iter().map(|x| x.io_ms).collect()),
                    max(&|x| x.io_ms),
                    st.iter().map(|x| x.cache_hits).sum::<usize>(),
                    st.iter().map(|x| x.evictions).sum::<usize>(),
                    max(&|x| x.resident_mib),
                    max(&|x| x.budget_mib),
                    st.iter().map(|x| x.queue_depth).max().unwrap_or(0),
                );
            }
            s.push_str(
                "\n### Out-of-core real time (every played frame)\n\n\
                 | flight | tau | mode | frames played | waited for I/O after frame 1 | \
                 drawn at needed level | late MiB median / max | needed MiB median | \
                 prefetched MiB/frame | behind schedule | peak resident MiB |\n\
                 |---|---:|---|---:|---:|---:|---|---:|---:|---:|---:|\n",
            );
            for r in ooc.iter().filter_map(|r| r.stream.as_ref().map(|x| (r, x))) {
                let (r, x) = r;
                let _ = writeln!(
                    s,
                    "| {} | {} | {} | {} | {} | {:.1} % | {:.3} / {:.3} | {:.3} | {:.3} | {} | {:.2} |",
                    r.flight,
                    r.value,
                    if x.real_time { "real time" } else { "warm (--wait)" },
                    x.frames,
                    x.waited_after_first,
                    100.0 * x.at_needed_level_share,
                    x.late_mib_median,
                    x.late_mib_max,
                    x.needed_mib_median,
                    x.prefetched_mib_mean,
                    x.behind_schedule,
                    x.peak_resident_mib,
                );
            }
        }
        s.push_str(
            "\nMedians over the frames. Triangles are non-degenerate ones; CPU ms and frame ms as \
             in the notes above; error figures leave out the frames missing data (blocks in \
             view that could not be read or drawn: holes in the picture); popping is the RMS change of the height error between \
             consecutive measured frames, RMSE change the change of the RMSE (the DSS paper's \
             measure), height jump the largest change of the drawn height at one DEM sample.\n",
        );
        s
    }
}
