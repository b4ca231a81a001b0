//! The benchmark: every LOD method over every flight with identical cameras, each method's
//! threshold swept, every frame timed by stage and measured exactly against the full DEM.
//!
//! Per frame ([`FrameRecord`], through the one frame loop [`crate::method::FrameLoop`]): the
//! selection (timed), the drawn surface rebuilt on the CPU with the renderer's reference
//! (terrain-gpu's tessellator, morph or paged lookup, so the measurement sees exactly what the
//! GPU draws; timed), the errors ([`terrain_core::measure::Measurer`]), and, when a GPU exists,
//! the frame drawn by the method's renderer (CPU encode/upload, wall and GPU times where the
//! adapter's timestamps are trustworthy). [`BenchReport`] serialises to JSON and renders
//! Markdown ([`BenchReport::to_markdown`]) and a hand-written SVG ([`BenchReport::to_svg`]):
//! triangles and CPU milliseconds against the 99th-percentile pixel error, one curve per method.
//!
//! Pixel errors (and the DSS methods' pixel threshold) are those of a
//! [`BenchConfig::measure_viewport`] view whatever the rendered image size, so quick and full
//! runs compare. Everything but the timings is deterministic: fixed flights, fixed sweep values,
//! frames and runs in a fixed order.

mod config;
mod markdown;
mod record;
mod run;
mod svg;

pub use crate::clock::{process_cpu_s, thread_cpu_s};
pub use crate::method::entropy_extra;
pub use crate::method::registry::{apply_parameter, sweep_values};
pub use config::{BenchConfig, OocCalibration, frame_indices, pick_evenly};
pub use record::{BenchReport, FlightInfo, FrameRecord, RunRecord, RunSummary, median, rss_bytes};
pub use run::{BenchProgress, print_progress, run_bench};

#[cfg(test)]
mod tests {
    use terrain_core::measure::FrameErrors;

    use super::record::median;
    use super::svg::log_range;
    use super::*;
    use crate::methods::LodMethod;

    #[test]
    fn sweeps_frames_and_medians() {
        assert_eq!(pick_evenly(&[1.0, 2.0, 3.0, 4.0, 5.0], 3), vec![1.0, 3.0, 5.0]);
        assert_eq!(pick_evenly(&[1.0, 2.0], 5), vec![1.0, 2.0]);
        assert_eq!(frame_indices(10, 0), (0..10).collect::<Vec<_>>());
        assert_eq!(frame_indices(101, 3), vec![0, 50, 100]);
        assert_eq!(sweep_values(LodMethod::Uniform, 16).1, vec![16.0, 8.0, 4.0, 2.0]);
        assert_eq!(sweep_values(LodMethod::Uniform, 4).1, vec![4.0, 2.0]);
        assert_eq!(median(vec![3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(vec![4.0, 1.0, 2.0, 3.0]), 2.5);
        assert_eq!(median(vec![]), 0.0);
        assert_eq!(log_range([0.5, 20.0].into_iter()), (-1.0, 2.0));
    }

    #[test]
    fn summary_reports_rmse_change_and_height_jumps() {
        let frame = |rmse: f64, change: Option<f64>, jump: f64| FrameRecord {
            frame: 0,
            patches: 1,
            triangles: 2,
            selection_ms: 0.0,
            cpu_tess_ms: 0.0,
            measure_ms: 0.0,
            encode_ms: None,
            render_ms: None,
            gpu_ms: None,
            gpu_draw_ms: None,
            gpu_tessellated: None,
            upload_bytes: None,
            cpu_ms: 0.0,
            frame_ms: 0.0,
            rss_bytes: None,
            errors: FrameErrors {
                rmse_m: rmse,
                rmse_change_m: change,
                popping_max_m: jump,
                ..FrameErrors::default()
            },
            ..FrameRecord::default()
        };
        // The first frame has no previous one: no change, no jump.
        let frames =
            [frame(5.0, None, 0.0), frame(7.0, Some(2.0), 3.0), frame(6.0, Some(1.0), 9.0)];
        let s = RunSummary::new(&frames);
        assert_eq!(s.median_rmse_change_m, 1.5);
        assert_eq!(s.median_max_jump_m, 6.0);
        assert_eq!(s.max_popping_m, 9.0);
        assert_eq!(s.median_rmse_m, 6.0);
    }

    #[test]
    fn frames_missing_data_are_counted_and_not_scored() {
        let frame = |p99: f64, missing_blocks: usize| FrameRecord {
            triangles: if missing_blocks > 0 { 0 } else { 10 },
            missing_blocks,
            errors: FrameErrors { p99_px: p99, rmse_m: p99, ..FrameErrors::default() },
            ..FrameRecord::default()
        };
        // A frame with every block missing measures nothing: its zeros are not a perfect score.
        let frames = [frame(0.0, 4), frame(2.0, 0), frame(3.0, 0)];
        let s = RunSummary::new(&frames);
        assert_eq!(s.frames_missing_data, 1);
        assert_eq!((s.median_p99_px, s.median_rmse_m), (2.5, 2.5));
        let all = RunSummary::new(&[frame(0.0, 4), frame(0.0, 9)]);
        assert_eq!(all.frames_missing_data, 2);
        assert!(all.median_p99_px.is_nan() && all.max_px.is_nan() && all.median_rmse_m.is_nan());
        let report = BenchReport {
            terrain: "t".into(),
            grid: [3, 3],
            adapter: None,
            timing_notes: Vec::new(),
            leaf_cells: 16,
            measure_viewport: [1280, 720],
            render_size: None,
            flights: vec![FlightInfo {
                name: "f".into(),
                total_frames: 2,
                frames: vec![0, 1],
                warnings: Vec::new(),
            }],
            runs: vec![RunRecord {
                flight: "f".into(),
                method: LodMethod::OutOfCore,
                from_store: false,
                parameter: "tau",
                value: 2.0,
                summary: all,
                frames: vec![frame(0.0, 4), frame(0.0, 9)],
                stream: None,
            }],
        };
        let md = report.to_markdown();
        let row = md.lines().find(|l| l.starts_with("| ooc")).unwrap();
        assert!(row.contains("n/a / n/a") && row.ends_with("| 2 of 2 (not scored) |"), "{row}");
        let json = serde_json::to_string(&report).unwrap();
        assert!(json.contains("\"median_p99_px\":null") && json.contains("\"missing_blocks\":9"));
        assert!(FrameRecord::CSV_HEADER.ends_with(",missing_blocks"));
        assert!(frame(0.0, 9).csv_row().ends_with(",9"));
    }
}
