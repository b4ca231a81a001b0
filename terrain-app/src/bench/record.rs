//! What the benchmark records: one [`FrameRecord`] per frame, a [`RunSummary`] (medians and
//! extremes) per run, and the whole [`BenchReport`]; resident memory and CPU clocks.

use serde::Serialize;
use terrain_core::measure::FrameErrors;

use crate::methods::LodMethod;
use crate::ooc::StreamRecord;

/// One frame: what was drawn, what it cost by stage, and how wrong it was.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct FrameRecord {
    /// Frame index in the flight (frame `k` at `t = k / fps`).
    pub frame: usize,
    /// Patches selected.
    pub patches: usize,
    /// Non-degenerate triangles of the tessellation (the GPU draws the same).
    pub triangles: u64,
    /// CPU time of the selection, ms.
    pub selection_ms: f64,
    /// CPU time of the tessellator reference building the drawn surface (tessellate, weld,
    /// displace), ms: the tessellation stage when measuring.
    pub cpu_tess_ms: f64,
    /// CPU time of the error measurement, ms (not part of a frame's cost).
    pub measure_ms: f64,
    /// Renderer CPU time to upload, encode and submit the frame, ms (rendered frames only).
    pub encode_ms: Option<f64>,
    /// Wall time of the renderer's call, including the wait for the GPU, ms.
    pub render_ms: Option<f64>,
    /// GPU time of the frame where trustworthy, ms.
    pub gpu_ms: Option<f64>,
    /// GPU time of the draw pass, ms.
    pub gpu_draw_ms: Option<f64>,
    /// Whether the GPU tessellation pass ran (false: the patch list was unchanged).
    pub gpu_tessellated: Option<bool>,
    /// Bytes the renderer uploaded this frame (frame uniform; patch rects, factors and ranges
    /// when the list changed; column/row offsets when the anchor moved).
    pub upload_bytes: Option<u64>,
    /// The frame's CPU cost: selection + encode when rendered, selection + CPU tessellation
    /// otherwise, ms. The plots' CPU axis.
    pub cpu_ms: f64,
    /// Selection + render wall time when rendered (selection + CPU tessellation otherwise), ms.
    pub frame_ms: f64,
    /// The stitching-strip methods (from memory): CPU time of the multilevel update (DSS
    /// section 3.3.1), ms; part of `selection_ms`. The DSS paper's Fig. 20 stages.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub update_ms: Option<f64>,
    /// The stitching-strip methods (from memory): CPU time of the strips' and P-blocks'
    /// construction (section 3.2), ms; part of `selection_ms`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub strips_ms: Option<f64>,
    /// Resident memory after the frame, bytes (`/proc/self/statm`; `None` elsewhere).
    pub rss_bytes: Option<u64>,
    /// Blocks in view the frame has no data for (a store-backed method: blocks whose levels
    /// could not be read, or that found no page slot): the picture has holes there and the
    /// errors are of the rest only, so such a frame is not scored ([`RunSummary`] leaves it
    /// out of the error figures and counts it in `frames_missing_data`).
    pub missing_blocks: usize,
    /// The measured errors.
    #[serde(flatten)]
    pub errors: FrameErrors,
    /// Geomorph only: the largest per-vertex height jump of the drawn surface from the
    /// flight's previous frame (consecutive flight frames, whatever the sampling), metres
    /// (`terrain_gpu::geomorph::max_vertex_jump`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub vertex_jump_m: Option<f64>,
    /// Geomorph only: the same with tweening off (integer levels): the popping geomorphing
    /// removes.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub vertex_jump_no_morph_m: Option<f64>,
    /// Geomorph only (rendered frames): material passes skipped because the material's alpha
    /// is zero over the patch.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub material_passes_skipped: Option<usize>,
    /// The out-of-core method's streaming statistics (the paper's Table 3 columns and the
    /// cache's); `None` for the other methods.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stream: Option<StreamRecord>,
}

impl FrameRecord {
    /// A frame measured on the CPU and not (yet) rendered: the stage times, the drawn size and
    /// the errors; CPU and frame ms are selection plus CPU tessellation until a render
    /// replaces them. The rest stays at its default.
    pub fn measured(
        frame: usize,
        patches: usize,
        triangles: u64,
        [selection_ms, cpu_tess_ms, measure_ms]: [f64; 3],
        errors: FrameErrors,
    ) -> Self {
        Self {
            frame,
            patches,
            triangles,
            selection_ms,
            cpu_tess_ms,
            measure_ms,
            cpu_ms: selection_ms + cpu_tess_ms,
            frame_ms: selection_ms + cpu_tess_ms,
            errors,
            ..Self::default()
        }
    }

    /// The CSV header matching [`FrameRecord::csv_row`].
    pub const CSV_HEADER: &'static str = "frame,patches,triangles,selection_ms,cpu_tess_ms,\
measure_ms,encode_ms,render_ms,gpu_ms,gpu_draw_ms,upload_bytes,cpu_ms,frame_ms,rss_bytes,\
max_px,p99_px,rmse_m,max_abs_m,popping_rms_m,popping_max_m,false_culls,culled_samples,samples,stride,\
missing_blocks";

    /// One CSV row (empty cells for absent values).
    pub fn csv_row(&self) -> String {
        let o = |x: Option<f64>| x.map(|x| format!("{x:.4}")).unwrap_or_default();
        let u = |x: Option<u64>| x.map(|x| x.to_string()).unwrap_or_default();
        let e = &self.errors;
        format!(
            "{},{},{},{:.4},{:.4},{:.4},{},{},{},{},{},{:.4},{:.4},{},{:.5},{:.5},{:.5},{:.5},{:.5},{:.5},{},{},{},{},{}",
            self.frame,
            self.patches,
            self.triangles,
            self.selection_ms,
            self.cpu_tess_ms,
            self.measure_ms,
            o(self.encode_ms),
            o(self.render_ms),
            o(self.gpu_ms),
            o(self.gpu_draw_ms),
            u(self.upload_bytes),
            self.cpu_ms,
            self.frame_ms,
            u(self.rss_bytes),
            e.max_px,
            e.p99_px,
            e.rmse_m,
            e.max_abs_m,
            e.popping_rms_m,
            e.popping_max_m,
            e.false_culls,
            e.culled_samples,
            e.samples,
            e.stride,
            self.missing_blocks
        )
    }
}

/// Resident set size from `/proc/self/statm` (pages of 4 KiB assumed), if readable.
pub fn rss_bytes() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/statm").ok()?;
    let pages: u64 = s.split_whitespace().nth(1)?.parse().ok()?;
    Some(pages * 4096)
}

/// Medians and extremes of one run's frames. The error figures (pixel errors, RMSE, popping,
/// false culls) are over the frames with all their data ([`FrameRecord::missing_blocks`] 0):
/// a frame with holes is not scored as if its picture were right; with no such frame they are
/// `NaN` (`null` in JSON, `n/a` in Markdown).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RunSummary {
    /// Frames measured.
    pub frames: usize,
    /// Frames with blocks in view they had no data for (left out of the error figures).
    pub frames_missing_data: usize,
    /// Median patches.
    pub median_patches: f64,
    /// Median non-degenerate triangles.
    pub median_triangles: f64,
    /// Median selection time, ms.
    pub median_selection_ms: f64,
    /// Median CPU tessellation (reference) time, ms.
    pub median_cpu_tess_ms: f64,
    /// Median frame CPU cost ([`FrameRecord::cpu_ms`]), ms.
    pub median_cpu_ms: f64,
    /// Median frame time ([`FrameRecord::frame_ms`]), ms.
    pub median_frame_ms: f64,
    /// Median trustworthy GPU time, ms (`None` when no frame had one).
    pub median_gpu_ms: Option<f64>,
    /// Median GPU draw-pass time, ms.
    pub median_gpu_draw_ms: Option<f64>,
    /// Median of the frames' p99 pixel error.
    pub median_p99_px: f64,
    /// Largest p99 pixel error of any frame.
    pub max_p99_px: f64,
    /// Largest pixel error of any frame.
    pub max_px: f64,
    /// Median RMSE, metres.
    pub median_rmse_m: f64,
    /// Largest `|delta|` of any frame, metres.
    pub max_abs_m: f64,
    /// Median popping RMS (frames after the first), metres.
    pub median_popping_rms_m: f64,
    /// Largest popping of any frame, metres: the largest per-vertex height jump, i.e. the
    /// largest `|drawn_k - drawn_(k-1)|` at a measured DEM sample seen in both frames (the
    /// sample's DEM height is the same in both, so the change of `delta` is the change of the
    /// drawn surface there: what the eye sees as a pop).
    pub max_popping_m: f64,
    /// Median over frames after the first of the frame's largest height jump, metres.
    pub median_max_jump_m: f64,
    /// Median over frames after the first of `|RMSE_k - RMSE_(k-1)|` (the DSS paper's
    /// "change of RMSE", section 5), metres.
    pub median_rmse_change_m: f64,
    /// False culls summed over the frames.
    pub false_culls: usize,
    /// Largest resident memory seen, bytes.
    pub max_rss_bytes: Option<u64>,
    /// Mean bytes uploaded per rendered frame.
    pub mean_upload_bytes: Option<f64>,
    /// Geomorph only: the largest per-vertex jump between consecutive flight frames, metres.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_vertex_jump_m: Option<f64>,
    /// Geomorph only: the same with tweening off.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_vertex_jump_no_morph_m: Option<f64>,
}

/// The median of `v` (0 for none).
pub fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 { v[n / 2] } else { 0.5 * (v[n / 2 - 1] + v[n / 2]) }
}

impl RunSummary {
    /// Summarises `frames`.
    pub fn new(all: &[FrameRecord]) -> Self {
        let med = |f: &dyn Fn(&FrameRecord) -> f64| median(all.iter().map(f).collect());
        // The error figures: the frames with all their data only, NaN without any.
        let scored: Vec<&FrameRecord> = all.iter().filter(|r| r.missing_blocks == 0).collect();
        let none = scored.is_empty();
        let err_med = |v: Vec<f64>| if none { f64::NAN } else { median(v) };
        let err_max = |f: &dyn Fn(&FrameRecord) -> f64| {
            if none { f64::NAN } else { scored.iter().map(|r| f(r)).fold(0.0, f64::max) }
        };
        let frames = all;
        let opt_med = |f: &dyn Fn(&FrameRecord) -> Option<f64>| {
            let v: Vec<f64> = frames.iter().filter_map(f).collect();
            (!v.is_empty()).then(|| median(v))
        };
        let uploads: Vec<u64> = frames.iter().filter_map(|r| r.upload_bytes).collect();
        Self {
            frames: frames.len(),
            median_patches: med(&|r| r.patches as f64),
            median_triangles: med(&|r| r.triangles as f64),
            median_selection_ms: med(&|r| r.selection_ms),
            median_cpu_tess_ms: med(&|r| r.cpu_tess_ms),
            median_cpu_ms: med(&|r| r.cpu_ms),
            median_frame_ms: med(&|r| r.frame_ms),
            median_gpu_ms: opt_med(&|r| r.gpu_ms),
            median_gpu_draw_ms: opt_med(&|r| r.gpu_draw_ms),
            frames_missing_data: all.len() - scored.len(),
            median_p99_px: err_med(scored.iter().map(|r| r.errors.p99_px).collect()),
            max_p99_px: err_max(&|r| r.errors.p99_px),
            max_px: err_max(&|r| r.errors.max_px),
            median_rmse_m: err_med(scored.iter().map(|r| r.errors.rmse_m).collect()),
            max_abs_m: err_max(&|r| r.errors.max_abs_m),
            median_popping_rms_m: err_med(
                scored.iter().skip(1).map(|r| r.errors.popping_rms_m).collect(),
            ),
            max_popping_m: err_max(&|r| r.errors.popping_max_m),
            median_max_jump_m: err_med(
                scored.iter().skip(1).map(|r| r.errors.popping_max_m).collect(),
            ),
            median_rmse_change_m: err_med(
                scored.iter().filter_map(|r| r.errors.rmse_change_m).collect(),
            ),
            false_culls: scored.iter().map(|r| r.errors.false_culls).sum(),
            max_rss_bytes: frames.iter().filter_map(|r| r.rss_bytes).max(),
            mean_upload_bytes: (!uploads.is_empty())
                .then(|| uploads.iter().sum::<u64>() as f64 / uploads.len() as f64),
            max_vertex_jump_m: frames.iter().filter_map(|r| r.vertex_jump_m).reduce(f64::max),
            max_vertex_jump_no_morph_m: frames
                .iter()
                .filter_map(|r| r.vertex_jump_no_morph_m)
                .reduce(f64::max),
        }
    }
}

/// One method at one parameter value over one flight.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RunRecord {
    /// The flight's name.
    pub flight: String,
    /// The method.
    pub method: LodMethod,
    /// Whether an in-memory method ran from the benchmark's store (`--from-store`).
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub from_store: bool,
    /// The swept parameter's name (`factor`, `C1`, `rho_thr`).
    pub parameter: &'static str,
    /// Its value.
    pub value: f64,
    /// Medians and extremes.
    pub summary: RunSummary,
    /// Every frame.
    pub frames: Vec<FrameRecord>,
    /// The out-of-core method: streaming over every played frame of the flight.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stream: Option<crate::ooc::StreamSummary>,
}

impl RunRecord {
    /// The method's name in reports: `(store)` appended for an in-memory method run from the
    /// store.
    pub fn label(&self) -> String {
        if self.from_store {
            format!("{} (store)", self.method.name())
        } else {
            self.method.name().to_string()
        }
    }
}

/// A flight as the benchmark flew it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FlightInfo {
    /// Its name.
    pub name: String,
    /// Frames in the whole flight.
    pub total_frames: usize,
    /// The frame indices measured.
    pub frames: Vec<usize>,
    /// Clamping warnings, as text.
    pub warnings: Vec<String>,
}

/// The whole benchmark: the set-up, the adapter and which timings to trust, and every run.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BenchReport {
    /// The terrain's name.
    pub terrain: String,
    /// Grid size, samples.
    pub grid: [usize; 2],
    /// The adapter ([`GpuContext::describe`]), or `None` when nothing was rendered.
    pub adapter: Option<String>,
    /// What the timings mean and which to trust.
    pub timing_notes: Vec<String>,
    /// Cells per side of the finest patch.
    pub leaf_cells: u32,
    /// The viewport of selection and pixel errors.
    pub measure_viewport: [u32; 2],
    /// The rendered image size, when rendering.
    pub render_size: Option<[u32; 2]>,
    /// The flights.
    pub flights: Vec<FlightInfo>,
    /// The runs: flights in the given order, then methods, then parameter values.
    pub runs: Vec<RunRecord>,
}
