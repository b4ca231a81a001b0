//! The benchmark: every LOD method over every flight with identical cameras, each method's
//! threshold swept, every frame timed by stage and measured exactly against the full DEM.
//!
//! Per frame ([`FrameRecord`]): the selection (timed), the drawn surface rebuilt on the CPU with
//! terrain-gpu's tessellator reference ([`terrain_gpu::tess::tessellate`], so the measurement
//! sees exactly what the GPU draws; timed), the errors ([`Measurer`]), and, when a GPU exists,
//! the frame drawn by [`TerrainRenderer`] (CPU encode/upload, wall and GPU times where the
//! adapter's timestamps are trustworthy). [`BenchReport`] serialises to JSON and renders
//! Markdown ([`BenchReport::to_markdown`]) and a hand-written SVG ([`BenchReport::to_svg`]):
//! triangles and CPU milliseconds against the 99th-percentile pixel error, one curve per method.
//!
//! Pixel errors (and the DSS methods' pixel threshold) are those of a
//! [`BenchConfig::measure_viewport`] view whatever the rendered image size, so quick and full
//! runs compare. Everything but the timings is deterministic: fixed flights, fixed sweep values,
//! frames and runs in a fixed order.

use std::fmt::Write as _;
use std::time::Instant;

use glam::dvec2;
use serde::Serialize;
use terrain_core::Heightmap;
use terrain_core::flight::{FlightConfig, FlightSpec, FlightWarning};
use terrain_core::geometry::Camera;
use terrain_core::lod::SurfaceMesh;
use terrain_core::measure::{FrameErrors, MeasureConfig, Measurer};
use terrain_gpu::geomorph::{GeomorphConfig, GeomorphOptions, GeomorphRenderer, max_vertex_jump};
use terrain_gpu::render::{DrawPatch, ExtraTriangles};
use terrain_gpu::tess::{GpuDomainPoint, GpuPatchFactors, PatchRange};
use terrain_gpu::{GpuContext, RenderConfig, RenderOptions, TerrainRenderer};

use crate::entropy_method::whole_terrain_selection;
use crate::methods::{LodMethod, MethodConfig, MethodScene, drawn_surface_of};
use crate::ooc::{OocConfig, OocScene, StreamRecord};

/// How a benchmark runs.
#[derive(Debug, Clone, PartialEq)]
pub struct BenchConfig {
    /// Methods, in report order. Default [`LodMethod::ALL`].
    pub methods: Vec<LodMethod>,
    /// Frames per flight: at most this many, evenly spaced over the flight (first and last
    /// included); 0 = every frame. Popping is then measured between consecutive *sampled*
    /// frames. Default 60.
    pub max_frames: usize,
    /// Sweep points per method, taken evenly from [`sweep_values`]' full list (which has 4-6).
    /// Default 5.
    pub sweep_points: usize,
    /// Rendered image size when a GPU is given; `None` measures without rendering. Default
    /// `Some((640, 360))`.
    pub render_size: Option<(u32, u32)>,
    /// The viewport of the flights' cameras, for selection (DSS's pixel threshold) and pixel
    /// errors. Default 1280 x 720.
    pub measure_viewport: (u32, u32),
    /// The methods' settings (leaf cells, defaults of the parameters not swept). Default
    /// [`MethodConfig::default`].
    pub method: MethodConfig,
    /// A scene folder (`terrain bake`'s output) whose PVS files `pvps-c-pvs` and `pvps-c-cons`
    /// use; an unreadable or mismatched file is a warning and that method runs without
    /// occlusion culling. `None`: the PVS is baked in memory with `method.pvs`. Default `None`.
    pub scene: Option<std::path::PathBuf>,
    /// How frames are measured. Default [`MeasureConfig::default`] (2,000,000 samples: stride 1
    /// up to about 1400 x 1400). A stride above 1 can land every measured sample on tessellation
    /// vertices (stride 2 and a uniform factor of half the leaf cells measure zero error), so
    /// strided figures are biased low; the stride used is in every frame's record.
    pub measure: MeasureConfig,
    /// The out-of-core method (`ooc`): a store baked from the same DEM; `None` (the default)
    /// bakes one into a temporary folder (blocks of `2^ooc_k + 1` vertices, lossless for
    /// integer and scaled-grey sources, else 1 cm) and removes it afterwards.
    pub ooc_store: Option<std::path::PathBuf>,
    /// `k` of the temporary store. Default 8 (the store's default, 257^2 blocks).
    pub ooc_k: u8,
    /// The out-of-core runtime's settings (tau is swept; budget, threads, page capacity).
    pub ooc: OocConfig,
}

impl Default for BenchConfig {
    fn default() -> Self {
        Self {
            methods: LodMethod::ALL.to_vec(),
            max_frames: 60,
            sweep_points: 5,
            render_size: Some((640, 360)),
            measure_viewport: (1280, 720),
            method: MethodConfig::default(),
            scene: None,
            measure: MeasureConfig::default(),
            ooc_store: None,
            ooc_k: 8,
            ooc: OocConfig::default(),
        }
    }
}

impl BenchConfig {
    /// The `--quick` settings: 20 frames per flight, 3 sweep points, 320 x 180 images and a
    /// 200,000-sample budget per frame (strided on large grids: errors biased low, see `measure`).
    pub fn quick() -> Self {
        Self {
            max_frames: 20,
            sweep_points: 3,
            render_size: Some((320, 180)),
            measure: MeasureConfig { max_samples: 200_000, ..MeasureConfig::default() },
            ..Self::default()
        }
    }
}

/// The swept parameter of `method`: its name and its full list of values, most detailed
/// first. `uniform`: the factor, `leaf_cells / 8 .. leaf_cells` (factor `leaf_cells` is full
/// resolution); PVPS: Eq. 8's `C1` (larger splits less); DSS: `rho_thr` in pixels.
pub fn sweep_values(method: LodMethod, leaf_cells: u32) -> (&'static str, Vec<f64>) {
    match method {
        LodMethod::Uniform => {
            let l = f64::from(leaf_cells.max(2));
            let mut v: Vec<f64> = [l, l / 2.0, l / 4.0, l / 8.0].map(|f| f.max(2.0)).to_vec();
            v.dedup();
            ("factor", v)
        }
        LodMethod::PvpsA | LodMethod::PvpsB | LodMethod::PvpsC => {
            ("C1", vec![12.5, 25.0, 50.0, 100.0, 200.0])
        }
        LodMethod::Dss1 | LodMethod::Dss2 | LodMethod::DssStrips => {
            ("rho_thr", vec![0.25, 0.5, 1.0, 2.0, 4.0, 8.0])
        }
        // E0 in percent of the largest entropy (the paper's 10..18 barely simplify at our
        // entropy scale; see `terrain_visibility::entropy::source::EntropyScale`). E0 = 0 is
        // the full-depth mesh, the uniform method's job, and seconds per frame: not swept.
        LodMethod::Entropy => ("E0", vec![18.0, 50.0, 70.0, 85.0, 95.0]),
        LodMethod::Geomorph => ("tau_px", vec![0.5, 1.0, 2.0, 4.0, 8.0]),
        LodMethod::PvpsCPvs | LodMethod::PvpsCConservative => {
            ("C1", vec![12.5, 25.0, 50.0, 100.0, 200.0])
        }
        // Qiu 2013 Eq. 7 threshold, pixels (the paper's figures use 2).
        LodMethod::OutOfCore => ("tau", vec![0.5, 1.0, 2.0, 4.0, 8.0]),
    }
}

/// `points` values taken evenly from `all` (both ends included); all of them when `points`
/// is at least their number.
pub fn pick_evenly(all: &[f64], points: usize) -> Vec<f64> {
    let n = all.len();
    if points >= n || n == 0 {
        return all.to_vec();
    }
    if points <= 1 {
        return vec![all[n / 2]];
    }
    let mut v: Vec<f64> = (0..points)
        .map(|k| all[((k * (n - 1)) as f64 / (points - 1) as f64).round() as usize])
        .collect();
    v.dedup();
    v
}

/// The frame indices of a flight of `n` frames: at most `max` evenly spaced (0 = all).
pub fn frame_indices(n: usize, max: usize) -> Vec<usize> {
    if max == 0 || max >= n {
        return (0..n).collect();
    }
    if max == 1 {
        return vec![0];
    }
    let mut v: Vec<usize> =
        (0..max).map(|k| ((k * (n - 1)) as f64 / (max - 1) as f64).round() as usize).collect();
    v.dedup();
    v
}

/// Sets `method`'s swept parameter in `config`.
pub fn apply_parameter(config: &mut MethodConfig, method: LodMethod, value: f64) {
    match method {
        LodMethod::Uniform => config.uniform_factor = value as f32,
        LodMethod::PvpsA | LodMethod::PvpsB | LodMethod::PvpsC => config.pvps.c1 = value,
        LodMethod::Dss1 | LodMethod::Dss2 | LodMethod::DssStrips => config.dss.rho_thr = value,
        LodMethod::Entropy => config.entropy.e0 = value,
        LodMethod::Geomorph => config.geomip.pixel_threshold = value,
        LodMethod::PvpsCPvs | LodMethod::PvpsCConservative => config.pvps.c1 = value,
        // tau belongs to the out-of-core runtime (OocConfig), set by run_bench.
        LodMethod::OutOfCore => {}
    }
}

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
    /// Resident memory after the frame, bytes (`/proc/self/statm`; `None` elsewhere).
    pub rss_bytes: Option<u64>,
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
max_px,p99_px,rmse_m,max_abs_m,popping_rms_m,popping_max_m,false_culls,culled_samples,samples,stride";

    /// One CSV row (empty cells for absent values).
    pub fn csv_row(&self) -> String {
        let o = |x: Option<f64>| x.map(|x| format!("{x:.4}")).unwrap_or_default();
        let u = |x: Option<u64>| x.map(|x| x.to_string()).unwrap_or_default();
        let e = &self.errors;
        format!(
            "{},{},{},{:.4},{:.4},{:.4},{},{},{},{},{},{:.4},{:.4},{},{:.5},{:.5},{:.5},{:.5},{:.5},{:.5},{},{},{},{}",
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
            e.stride
        )
    }
}

/// Resident set size from `/proc/self/statm` (pages of 4 KiB assumed), if readable.
pub fn rss_bytes() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/statm").ok()?;
    let pages: u64 = s.split_whitespace().nth(1)?.parse().ok()?;
    Some(pages * 4096)
}

/// CPU seconds of this thread (`/proc/thread-self/schedstat`, ns), for timings on a shared
/// machine where wall time includes waiting for a core; `NaN` where unavailable.
pub fn thread_cpu_s() -> f64 {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse::<f64>().ok())
        .map_or(f64::NAN, |ns| ns * 1e-9)
}

/// CPU seconds of the whole process, all threads (`/proc/self/stat` utime + stime, 10 ms
/// ticks); `NaN` where unavailable.
pub fn process_cpu_s() -> f64 {
    let Ok(s) = std::fs::read_to_string("/proc/self/stat") else { return f64::NAN };
    let after = s.rsplit_once(')').map_or("", |x| x.1);
    let f: Vec<&str> = after.split_whitespace().collect();
    match (
        f.get(11).and_then(|v| v.parse::<f64>().ok()),
        f.get(12).and_then(|v| v.parse::<f64>().ok()),
    ) {
        (Some(u), Some(k)) => (u + k) / 100.0,
        _ => f64::NAN,
    }
}

/// Runs frames of one method at one setting: selection, CPU surface, measurement, and the
/// optional render. Borrows the scene, so the caller changes the setting between runners.
#[derive(Debug)]
pub struct FrameRunner<'a> {
    scene: &'a MethodScene,
    method: LodMethod,
    measurer: Measurer<'a>,
    renderer: Option<&'a mut TerrainRenderer>,
    geomorph: Option<&'a mut GeomorphRenderer>,
    options: RenderOptions,
    last_anchor: Option<glam::DVec3>,
    first: bool,
}

impl<'a> FrameRunner<'a> {
    /// A runner of `method` on `scene` (its current config), rendering with `renderer` if given.
    pub fn new(
        scene: &'a MethodScene,
        method: LodMethod,
        measure: MeasureConfig,
        renderer: Option<&'a mut TerrainRenderer>,
    ) -> Self {
        Self {
            scene,
            method,
            measurer: Measurer::new(&scene.hm, &scene.qt, measure),
            renderer,
            geomorph: None,
            options: RenderOptions::default(),
            last_anchor: None,
            first: true,
        }
    }

    /// Renders the `geomorph` method with `renderer` (its own pipeline) when given.
    pub fn with_geomorph_renderer(mut self, renderer: Option<&'a mut GeomorphRenderer>) -> Self {
        self.geomorph = renderer;
        self
    }

    /// Like [`FrameRunner::frame`]; `previous` is the flight's previous camera, for the
    /// geomorph method's per-vertex jump (with and without tweening).
    pub fn frame_after(
        &mut self,
        frame: usize,
        camera: &Camera,
        previous: Option<&Camera>,
    ) -> anyhow::Result<FrameRecord> {
        if self.method == LodMethod::Geomorph {
            return self.geomorph_frame(frame, camera, previous);
        }
        self.frame(frame, camera)
    }

    /// The geomorph branch: its own selection, CPU morph reference and renderer.
    fn geomorph_frame(
        &mut self,
        frame: usize,
        camera: &Camera,
        previous: Option<&Camera>,
    ) -> anyhow::Result<FrameRecord> {
        let scene = self.scene;
        let t = Instant::now();
        let lods = scene.select_geomorph(camera);
        let selection_ms = ms(t);

        let t = Instant::now();
        let (mesh, triangle_count) = scene.geomorph_surface(&lods);
        let cpu_tess_ms = ms(t);

        let t = Instant::now();
        let selection = scene.geomorph_selection(&lods);
        let errors = self.measurer.measure(camera, &selection, &mesh);
        let measure_ms = ms(t);

        // Popping: the jump from the flight's previous frame, morphing and not (untimed).
        let (mut vertex_jump_m, mut vertex_jump_no_morph_m) = (None, None);
        if let Some(prev) = previous {
            let (before, _) = scene.geomorph_surface(&scene.select_geomorph(prev));
            vertex_jump_m = Some(max_vertex_jump(&before, &mesh));
            let mut off = scene.config.geomip;
            off.morph = false;
            off.patch_cells = scene.geomorph_patch_cells();
            let still =
                |c: &Camera| scene.geomorph_surface(&scene.geomip_scene().select(c, &off)).0;
            vertex_jump_no_morph_m = Some(max_vertex_jump(&still(prev), &still(camera)));
        }
        drop(mesh);

        let mut record = FrameRecord {
            vertex_jump_m,
            vertex_jump_no_morph_m,
            ..FrameRecord::measured(
                frame,
                lods.patches.len(),
                triangle_count,
                [selection_ms, cpu_tess_ms, measure_ms],
                errors,
            )
        };
        if let Some(renderer) = self.geomorph.as_deref_mut() {
            let t = Instant::now();
            let s = renderer.render(camera, &lods.patches, &GeomorphOptions::default())?;
            let render_ms = ms(t);
            let anchor = TerrainRenderer::anchor_for(camera.position);
            let mut bytes = s.upload_bytes;
            if self.last_anchor != Some(anchor) {
                bytes += 4 * (scene.hm.width() + scene.hm.height()) as u64;
            }
            self.last_anchor = Some(anchor);
            record.encode_ms = Some(s.cpu_ms);
            record.render_ms = Some(render_ms);
            record.upload_bytes = Some(bytes);
            record.material_passes_skipped = Some(s.passes_skipped);
            // The geomorph renderer has no compute pass: its CPU cost is selection + encode.
            record.cpu_ms = selection_ms + s.cpu_ms;
            record.frame_ms = selection_ms + render_ms;
        }
        record.rss_bytes = rss_bytes();
        Ok(record)
    }

    /// Selects, tessellates (CPU reference), measures and (optionally) renders frame `frame`.
    pub fn frame(&mut self, frame: usize, camera: &Camera) -> anyhow::Result<FrameRecord> {
        if self.method == LodMethod::Entropy {
            return self.entropy_frame(frame, camera);
        }
        let scene = self.scene;
        let t = Instant::now();
        let drawn = scene.frame(self.method, camera);
        let selection = &drawn.selection;
        let selection_ms = ms(t);

        let t = Instant::now();
        let (mesh, triangle_count) = scene.frame_surface(&drawn);
        let cpu_tess_ms = ms(t);

        let t = Instant::now();
        let errors = self.measurer.measure(camera, selection, &mesh);
        let measure_ms = ms(t);
        drop(mesh);

        let mut record = FrameRecord::measured(
            frame,
            selection.patches.len(),
            triangle_count,
            [selection_ms, cpu_tess_ms, measure_ms],
            errors,
        );
        if let Some(renderer) = self.renderer.as_deref_mut() {
            let (patches, extra) = scene.frame_draw(&drawn);
            let t = Instant::now();
            let s = renderer.render_with_extra(camera, &patches, &extra, &self.options)?;
            let render_ms = ms(t);
            let anchor = TerrainRenderer::anchor_for(camera.position);
            let mut bytes = 128u64;
            if s.tessellated || self.first {
                let per_patch = size_of::<GpuPatchFactors>() + size_of::<PatchRange>() + 16;
                bytes += (patches.len() * per_patch) as u64;
            }
            // Strips are uploaded every frame.
            bytes += (extra.points.len() * 16 + extra.indices.len() * 4) as u64;
            if self.last_anchor != Some(anchor) {
                bytes += 4 * (scene.hm.width() + scene.hm.height()) as u64;
            }
            self.last_anchor = Some(anchor);
            self.first = false;
            record.encode_ms = Some(s.cpu_ms);
            record.render_ms = Some(render_ms);
            record.gpu_ms = s.gpu_ms;
            record.gpu_draw_ms = s.gpu_draw_ms;
            record.gpu_tessellated = Some(s.tessellated);
            record.upload_bytes = Some(bytes);
            record.cpu_ms = selection_ms + s.cpu_ms;
            record.frame_ms = selection_ms + render_ms;
        }
        record.rss_bytes = rss_bytes();
        Ok(record)
    }

    /// A frame of the `entropy` method: the cut (Eq. 4-5) is the selection time; crack
    /// elimination and tile triangulation are the tessellation time; the mesh is measured on
    /// the CPU and drawn as the renderer's extra triangles ([`entropy_extra`]).
    fn entropy_frame(&mut self, frame: usize, camera: &Camera) -> anyhow::Result<FrameRecord> {
        let scene = self.scene;
        let f = scene.entropy_scene().frame(camera, &scene.config.entropy);
        let selection_ms = f.cut_ms;
        let cpu_tess_ms = f.crack_ms + f.triangulate_ms;
        let selection = whole_terrain_selection(f.tiles, selection_ms);
        let t = Instant::now();
        let errors = self.measurer.measure(camera, &selection, &f.surface);
        let measure_ms = ms(t);
        let mut record = FrameRecord {
            rss_bytes: rss_bytes(),
            ..FrameRecord::measured(
                frame,
                f.tiles,
                f.surface.triangles.len() as u64,
                [selection_ms, cpu_tess_ms, measure_ms],
                errors,
            )
        };
        if let Some(renderer) = self.renderer.as_deref_mut() {
            let t = Instant::now();
            let (carrier, extra) = entropy_extra(&scene.hm, &f.surface);
            let convert_ms = ms(t);
            let t = Instant::now();
            let s = renderer.render_with_extra(camera, &[carrier], &extra, &self.options)?;
            let render_ms = ms(t);
            record.encode_ms = Some(s.cpu_ms);
            record.render_ms = Some(render_ms);
            record.gpu_ms = s.gpu_ms;
            record.gpu_draw_ms = s.gpu_draw_ms;
            record.gpu_tessellated = Some(s.tessellated);
            // The whole mesh is uploaded every frame (16-byte points, 4-byte indices).
            record.upload_bytes =
                Some(128 + (extra.points.len() * 16 + extra.indices.len() * 4) as u64);
            record.cpu_ms = selection_ms + cpu_tess_ms + convert_ms + s.cpu_ms;
            record.frame_ms = selection_ms + cpu_tess_ms + convert_ms + render_ms;
        }
        Ok(record)
    }

    /// The renderer, for reading the last frame back.
    pub fn renderer(&mut self) -> Option<&mut TerrainRenderer> {
        self.renderer.as_deref_mut()
    }
}

/// A triangle mesh in grid coordinates (the entropy method's) as the renderer's extra
/// triangles: every vertex is a domain point of one carrier patch spanning the whole grid,
/// whose factors are 0 so that the tessellator emits nothing for it (a patch with an outer
/// factor `<= 0` is culled). The vertex stage maps `(u, v)` to `x0 + u (x1 - x0)`, so a vertex
/// at grid sample `i` lands within an f32 rounding of it, and samples the same heightmap.
pub fn entropy_extra(hm: &Heightmap, mesh: &SurfaceMesh) -> (DrawPatch, ExtraTriangles) {
    let (w, h) = ((hm.width() - 1).max(1) as f64, (hm.height() - 1).max(1) as f64);
    let carrier = DrawPatch {
        rect: [0, 0, w as u32, h as u32],
        factors: terrain_gpu::tess::PatchFactors::uniform(0.0),
    };
    let points = mesh
        .grid
        .iter()
        .map(|g| GpuDomainPoint {
            uv: [(g.x / w) as f32, (g.y / h) as f32],
            patch_index: 0,
            pad: 0,
        })
        .collect();
    let indices = mesh.triangles.iter().flatten().copied().collect();
    (carrier, ExtraTriangles { points, indices })
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// Medians and extremes of one run's frames.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RunSummary {
    /// Frames measured.
    pub frames: usize,
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
fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 { v[n / 2] } else { 0.5 * (v[n / 2 - 1] + v[n / 2]) }
}

impl RunSummary {
    /// Summarises `frames`.
    pub fn new(frames: &[FrameRecord]) -> Self {
        let med = |f: &dyn Fn(&FrameRecord) -> f64| median(frames.iter().map(f).collect());
        let opt_med = |f: &dyn Fn(&FrameRecord) -> Option<f64>| {
            let v: Vec<f64> = frames.iter().filter_map(f).collect();
            (!v.is_empty()).then(|| median(v))
        };
        let max = |f: &dyn Fn(&FrameRecord) -> f64| frames.iter().map(f).fold(0.0, f64::max);
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
            median_p99_px: med(&|r| r.errors.p99_px),
            max_p99_px: max(&|r| r.errors.p99_px),
            max_px: max(&|r| r.errors.max_px),
            median_rmse_m: med(&|r| r.errors.rmse_m),
            max_abs_m: max(&|r| r.errors.max_abs_m),
            median_popping_rms_m: median(
                frames.iter().skip(1).map(|r| r.errors.popping_rms_m).collect(),
            ),
            max_popping_m: max(&|r| r.errors.popping_max_m),
            median_max_jump_m: median(
                frames.iter().skip(1).map(|r| r.errors.popping_max_m).collect(),
            ),
            median_rmse_change_m: median(
                frames.iter().filter_map(|r| r.errors.rmse_change_m).collect(),
            ),
            false_culls: frames.iter().map(|r| r.errors.false_culls).sum(),
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
    /// The swept parameter's name (`factor`, `C1`, `rho_thr`).
    pub parameter: &'static str,
    /// Its value.
    pub value: f64,
    /// Medians and extremes.
    pub summary: RunSummary,
    /// Every frame.
    pub frames: Vec<FrameRecord>,
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

/// Progress of a benchmark: `done` of `total` frames, and what runs now.
#[derive(Debug, Clone, PartialEq)]
pub struct BenchProgress {
    /// Frames done.
    pub done: usize,
    /// Frames in all.
    pub total: usize,
    /// Flight, method and parameter now running.
    pub label: String,
}

/// A plain-text progress bar on stderr, rewritten in place.
pub fn print_progress(p: &BenchProgress) {
    let width = 30;
    let filled = (p.done * width).checked_div(p.total).unwrap_or(width);
    eprint!(
        "\r[{}{}] {}/{} {:<40}",
        "#".repeat(filled),
        " ".repeat(width - filled),
        p.done,
        p.total,
        p.label
    );
    if p.done == p.total {
        eprintln!();
    }
}

/// Runs the benchmark on `hm` (named `terrain`) over `flights`, rendering with `gpu` when given.
pub fn run_bench(
    terrain: &str,
    hm: Heightmap,
    flights: &[FlightSpec],
    cfg: &BenchConfig,
    gpu: Option<&GpuContext>,
    progress: &mut dyn FnMut(&BenchProgress),
) -> anyhow::Result<BenchReport> {
    let grid = [hm.width(), hm.height()];
    let flight_cfg = FlightConfig {
        viewport_px: dvec2(f64::from(cfg.measure_viewport.0), f64::from(cfg.measure_viewport.1)),
        ..FlightConfig::default()
    };
    let resolved: Vec<_> = flights.iter().map(|f| f.resolve(&hm, &flight_cfg)).collect();
    let infos: Vec<FlightInfo> = resolved
        .iter()
        .map(|(f, w)| FlightInfo {
            name: f.name.clone(),
            total_frames: f.frames().len(),
            frames: frame_indices(f.frames().len(), cfg.max_frames),
            warnings: w.iter().map(FlightWarning::to_string).collect(),
        })
        .collect();

    let render_size = cfg.render_size.filter(|_| gpu.is_some());
    let mut renderer = match (gpu, render_size) {
        (Some(ctx), Some((width, height))) => Some(TerrainRenderer::new(
            ctx,
            &hm,
            &RenderConfig { width, height, background: [150, 185, 225, 255], ..Default::default() },
        )?),
        _ => None,
    };
    let mut geomorph_renderer = match (gpu, render_size) {
        (Some(ctx), Some((width, height))) if cfg.methods.contains(&LodMethod::Geomorph) => {
            Some(GeomorphRenderer::new(
                ctx,
                &hm,
                &GeomorphConfig {
                    width,
                    height,
                    patch_cells: cfg.method.leaf_cells.clamp(2, 64),
                    background: [150, 185, 225, 255],
                    ..Default::default()
                },
            )?)
        }
        _ => None,
    };
    let mut notes = timing_notes(gpu, renderer.is_some());
    notes.push(format!(
        "Pixel errors and DSS's rho_thr refer to a {}x{} view; frames per flight: {}.",
        cfg.measure_viewport.0,
        cfg.measure_viewport.1,
        if cfg.max_frames == 0 { "all".to_string() } else { format!("at most {}", cfg.max_frames) }
    ));

    if cfg.methods.contains(&LodMethod::Entropy) {
        notes.push(
            "entropy: a triangle mesh, measured on the CPU and drawn as the renderer's extra \
             triangles (uploaded every frame); its selection time is the Eq. 5 cut, its \
             tessellation time the crack elimination and tile triangulation."
                .to_string(),
        );
    }
    let mut scene = MethodScene::new(hm, cfg.method.clone());
    if let Some(dir) = &cfg.scene {
        for warning in crate::scene_files::load(&scene, dir, &cfg.methods) {
            eprintln!("warning: {warning}");
            notes.push(warning);
        }
    }
    scene.prepare(&cfg.methods);
    let leaf_cells = scene.config.leaf_cells;
    let sweeps: Vec<(LodMethod, &'static str, Vec<f64>)> = cfg
        .methods
        .iter()
        .map(|&m| {
            let (name, all) = sweep_values(m, leaf_cells);
            (m, name, pick_evenly(&all, cfg.sweep_points))
        })
        .collect();
    let per_flight: usize = sweeps.iter().map(|s| s.2.len()).sum();
    let total: usize = infos.iter().map(|i| i.frames.len() * per_flight).sum();
    let mut done = 0;
    let mut runs = Vec::new();
    let mut ooc_store: Option<Result<std::sync::Arc<terrain_stream::Store>, String>> = None;
    for ((flight, _), info) in resolved.iter().zip(&infos) {
        for (method, parameter, values) in &sweeps {
            if *method == LodMethod::OutOfCore {
                let store = ooc_store.get_or_insert_with(|| prepare_store(&scene.hm, cfg));
                let store = match store {
                    Ok(s) => s.clone(),
                    Err(e) => anyhow::bail!("the out-of-core method's store: {e}"),
                };
                for &value in values {
                    let label = format!("{} ooc tau={value}", info.name);
                    let config = OocConfig { tau: value, ..cfg.ooc };
                    let frames = run_ooc(
                        &scene,
                        &store,
                        config,
                        cfg,
                        gpu,
                        render_size,
                        flight,
                        &info.frames,
                        &mut |_| {
                            done += 1;
                            progress(&BenchProgress { done, total, label: label.clone() });
                        },
                    )?;
                    runs.push(RunRecord {
                        flight: info.name.clone(),
                        method: *method,
                        parameter,
                        value,
                        summary: RunSummary::new(&frames),
                        frames,
                    });
                }
                continue;
            }
            for &value in values {
                let mut config = cfg.method.clone();
                config.leaf_cells = leaf_cells;
                config.pvps.leaf_cells = leaf_cells;
                config.dss.leaf_cells = leaf_cells;
                apply_parameter(&mut config, *method, value);
                scene.config = config;
                let label = format!("{} {} {parameter}={value}", info.name, method.name());
                let mut runner = FrameRunner::new(&scene, *method, cfg.measure, renderer.as_mut())
                    .with_geomorph_renderer(geomorph_renderer.as_mut());
                let mut frames = Vec::with_capacity(info.frames.len());
                for &k in &info.frames {
                    let cams = flight.frames();
                    frames.push(runner.frame_after(
                        k,
                        &cams[k],
                        k.checked_sub(1).map(|p| &cams[p]),
                    )?);
                    done += 1;
                    progress(&BenchProgress { done, total, label: label.clone() });
                }
                runs.push(RunRecord {
                    flight: info.name.clone(),
                    method: *method,
                    parameter,
                    value,
                    summary: RunSummary::new(&frames),
                    frames,
                });
            }
        }
    }
    if let (Some(Ok(store)), None) = (&ooc_store, &cfg.ooc_store) {
        let _ = std::fs::remove_dir_all(store.dir());
    }
    if ooc_store.is_some() {
        notes.push(
            "ooc: blocks come from a store through the streamer; every frame waits for the levels \
             it needs (warm), so its error is the selection's and the stream columns show what \
             was loaded on the frame thread and what the workers prefetched. Sampled frames are \
             further apart than the flight's frame rate, so Eq. 8's speed is overestimated."
                .to_string(),
        );
    }
    Ok(BenchReport {
        terrain: terrain.to_string(),
        grid,
        adapter: gpu.filter(|_| render_size.is_some()).map(GpuContext::describe),
        timing_notes: notes,
        leaf_cells,
        measure_viewport: [cfg.measure_viewport.0, cfg.measure_viewport.1],
        render_size: render_size.map(|(w, h)| [w, h]),
        flights: infos,
        runs,
    })
}

/// The store of the out-of-core method: the configured one, or `hm` baked into a temporary
/// folder (see [`BenchConfig::ooc_store`]).
fn prepare_store(
    hm: &Heightmap,
    cfg: &BenchConfig,
) -> Result<std::sync::Arc<terrain_stream::Store>, String> {
    use terrain_stream::{BakeConfig, BakeProgress, HeightEncoding, Store, bake};
    let dir = match &cfg.ooc_store {
        Some(d) => d.clone(),
        None => {
            let dir = std::env::temp_dir().join(format!(
                "terrain-bench-ooc-{}-{}",
                std::process::id(),
                hm.width()
            ));
            // Lossless where the heights lie on a 0.1 m lattice (scaled grey images, integer
            // DEMs), else the store's default 1 cm bound.
            let lattice = hm.data().iter().all(|&h| ((h * 10.0).round() - h * 10.0).abs() < 1e-3);
            let encoding = if lattice {
                HeightEncoding::Quantized { step_m: 0.1, offset_m: 0.0 }
            } else {
                HeightEncoding::default()
            };
            let config =
                BakeConfig { k: cfg.ooc_k, encoding, overwrite: true, ..Default::default() };
            bake(hm, &dir, &config, &mut |_: &BakeProgress| std::ops::ControlFlow::Continue(()))
                .map_err(|e| e.to_string())?;
            dir
        }
    };
    let store = Store::open(&dir).map_err(|e| e.to_string())?;
    let h = store.header();
    if (h.width, h.height) != (hm.width() as u64, hm.height() as u64) {
        return Err(format!(
            "{} is {} x {} samples, the DEM {} x {}",
            dir.display(),
            h.width,
            h.height,
            hm.width(),
            hm.height()
        ));
    }
    Ok(std::sync::Arc::new(store))
}

/// One out-of-core run (one tau) over one flight's sampled frames: a fresh runtime, warm
/// frames, the drawn surface rebuilt from the pages' heights (the CPU reference of the paged
/// renderer) and measured against the full DEM, the paged render when a GPU is given.
#[allow(clippy::too_many_arguments)]
fn run_ooc(
    scene: &MethodScene,
    store: &std::sync::Arc<terrain_stream::Store>,
    config: OocConfig,
    cfg: &BenchConfig,
    gpu: Option<&GpuContext>,
    render_size: Option<(u32, u32)>,
    flight: &terrain_core::flight::Flight,
    indices: &[usize],
    tick: &mut dyn FnMut(usize),
) -> anyhow::Result<Vec<FrameRecord>> {
    let mut ooc = OocScene::new(store.clone(), config).with_mirror();
    if ooc.root_cells() != scene.qt.root_cells() {
        anyhow::bail!(
            "the store's blocks ({} cells) do not tile the DEM's quadtree (root {} cells): bake with a smaller k",
            store.header().block_cells(),
            scene.qt.root_cells()
        );
    }
    let mut renderer = match (gpu, render_size) {
        (Some(ctx), Some((width, height))) => Some(ooc.renderer(
            ctx,
            &RenderConfig { width, height, background: [150, 185, 225, 255], ..Default::default() },
        )?),
        _ => None,
    };
    let mut measurer = Measurer::new(&scene.hm, &scene.qt, cfg.measure);
    let mut frames = Vec::with_capacity(indices.len());
    for &k in indices {
        let camera = &flight.frames()[k];
        let f = ooc.frame(camera, true);
        let selection_ms = f.selection.stats.cpu_time.as_secs_f64() * 1e3;
        let t = Instant::now();
        let drawn = ooc.mirror().expect("mirrored").to_heightmap(&scene.hm);
        let (mesh, triangles) = drawn_surface_of(&drawn, &scene.qt, &f.selection);
        let cpu_tess_ms = ms(t);
        drop(drawn);
        let t = Instant::now();
        let errors = measurer.measure(camera, &f.selection, &mesh);
        let measure_ms = ms(t);
        drop(mesh);
        let mut record = FrameRecord {
            stream: Some(f.stream.clone()),
            ..FrameRecord::measured(
                k,
                f.selection.patches.len(),
                triangles,
                [selection_ms, cpu_tess_ms, measure_ms],
                errors,
            )
        };
        if let Some(r) = renderer.as_mut() {
            OocScene::apply(r, &f)?;
            let t = Instant::now();
            let s = r.render(camera, &f.patches, &RenderOptions::default())?;
            let render_ms = ms(t);
            let pages: u64 = f.updates.iter().filter(|u| u.fill.is_some()).count() as u64;
            record.encode_ms = Some(s.cpu_ms);
            record.render_ms = Some(render_ms);
            record.gpu_ms = s.gpu_ms;
            record.gpu_draw_ms = s.gpu_draw_ms;
            record.gpu_tessellated = Some(s.tessellated);
            record.upload_bytes = Some(128 + pages * ooc.layout().page_len() as u64 * 4);
            record.cpu_ms = selection_ms + s.cpu_ms;
            record.frame_ms = selection_ms + render_ms;
        }
        record.rss_bytes = rss_bytes();
        frames.push(record);
        tick(k);
    }
    Ok(frames)
}

/// What the timings of a run on `gpu` mean, and which are trustworthy.
fn timing_notes(gpu: Option<&GpuContext>, rendered: bool) -> Vec<String> {
    let mut notes = vec![
        "Selection and CPU tessellation (the tessellator's CPU reference, as measured) are wall \
         times of single-threaded CPU work: trustworthy on an idle machine."
            .to_string(),
    ];
    match gpu.filter(|_| rendered) {
        None => notes.push(
            "Nothing was rendered (no GPU adapter): CPU ms = selection + CPU tessellation; no GPU times."
                .to_string(),
        ),
        Some(ctx) => {
            let f = &ctx.features;
            // `DeviceType::Cpu` without a direct wgpu dependency: lavapipe and llvmpipe.
            let software = format!("{:?}", ctx.adapter_info().device_type) == "Cpu";
            notes.push(
                "CPU ms = selection + the renderer's upload/encode/submit; frame ms = selection + \
                 the render call's wall time (it waits for the GPU)."
                    .to_string(),
            );
            if !f.timestamp_query {
                notes.push("GPU times: none (the adapter has no timestamp queries).".to_string());
            } else if !f.compute_timestamps_trustworthy {
                notes.push(
                    "GPU times: the compute (tessellation) pass's timestamps are untrustworthy on \
                     this adapter (lavapipe), so frame GPU ms is reported only for frames that \
                     reused the tessellation; the draw-pass time is reported always."
                        .to_string(),
                );
            } else {
                notes.push("GPU times: timestamp queries of both passes.".to_string());
            }
            if software {
                notes.push(
                    "The adapter is a software renderer: its 'GPU' work runs on the same CPU cores, \
                     so frame ms and GPU ms compare methods but do not predict hardware speed."
                        .to_string(),
                );
            }
        }
    }
    notes
}

/// A method's colour in the plots.
fn colour(m: LodMethod) -> &'static str {
    match m {
        LodMethod::Uniform => "#555555",
        LodMethod::PvpsA => "#1f77b4",
        LodMethod::PvpsB => "#2ca02c",
        LodMethod::PvpsC => "#d62728",
        LodMethod::Dss1 => "#9467bd",
        LodMethod::Dss2 => "#ff7f0e",
        LodMethod::Entropy => "#8c564b",
        LodMethod::Geomorph => "#e377c2",
        LodMethod::PvpsCPvs => "#bcbd22",
        LodMethod::PvpsCConservative => "#17becf",
        LodMethod::DssStrips => "#7f7f7f",
        LodMethod::OutOfCore => "#aec7e8",
    }
}

fn opt4(x: Option<f64>) -> String {
    x.map(|x| format!("{x:.4}")).unwrap_or_else(|| "n/a".to_string())
}

fn opt(x: Option<f64>) -> String {
    x.map(|x| format!("{x:.2}")).unwrap_or_else(|| "n/a".to_string())
}

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
                 height jump m (median / max) | false culls |\n\
                 |---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
            );
            for r in self.runs.iter().filter(|r| r.flight == f.name) {
                let m = &r.summary;
                let _ = writeln!(
                    s,
                    "| {} | {} = {} | {:.0} | {:.0} | {:.3} | {:.2} | {:.2} | {} | {:.3} / {:.3} | {:.3} | {:.3} | {:.4} | {:.4} | {:.3} / {:.3} | {} |",
                    r.method.name(),
                    r.parameter,
                    r.value,
                    m.median_triangles,
                    m.median_patches,
                    m.median_selection_ms,
                    m.median_cpu_ms,
                    m.median_frame_ms,
                    opt(m.median_gpu_ms),
                    m.median_p99_px,
                    m.max_p99_px,
                    m.max_px,
                    m.median_rmse_m,
                    m.median_popping_rms_m,
                    m.median_rmse_change_m,
                    m.median_max_jump_m,
                    m.max_popping_m,
                    m.false_culls
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
            self.runs.iter().filter(|r| r.method == LodMethod::OutOfCore).collect();
        if !ooc.is_empty() {
            s.push_str(
                "\n## Out-of-core streaming (the paper's Table 3 columns)\n\n\
                 | flight | tau | needed MB (median) | synchronous MB (sum) | sync loads after frame 1 | \
                 prefetched MB (sum) | I/O ms (median / max) | cache hits | evictions | \
                 peak resident MB | budget MB | max queue |\n\
                 |---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
            );
            for r in ooc {
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
                    median(st.iter().map(|x| x.needed_mb).collect()),
                    sum(&|x| x.sync_mb),
                    st.iter().skip(1).map(|x| x.sync_loads).sum::<usize>(),
                    sum(&|x| x.prefetched_mb),
                    median(st.iter().map(|x| x.io_ms).collect()),
                    max(&|x| x.io_ms),
                    st.iter().map(|x| x.cache_hits).sum::<usize>(),
                    st.iter().map(|x| x.evictions).sum::<usize>(),
                    max(&|x| x.resident_mb),
                    max(&|x| x.budget_mb),
                    st.iter().map(|x| x.queue_depth).max().unwrap_or(0),
                );
            }
        }
        s.push_str(
            "\nMedians over the frames. Triangles are non-degenerate ones; CPU ms and frame ms as \
             in the notes above; popping is the RMS change of the height error between \
             consecutive measured frames, RMSE change the change of the RMSE (the DSS paper's \
             measure), height jump the largest change of the drawn height at one DEM sample.\n",
        );
        s
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
            let runs: Vec<&RunRecord> = self.runs.iter().filter(|r| r.flight == f.name).collect();
            let y0 = legend_h + row as f64 * ph;
            let panels: [(&str, Axis); 2] =
                [("triangles", |m| m.median_triangles), ("CPU ms per frame", |m| m.median_cpu_ms)];
            for (col, (ylabel, yof)) in panels.into_iter().enumerate() {
                let title = format!("{}: {ylabel} vs p99 px ({})", f.name, self.terrain);
                let points: Vec<(LodMethod, f64, f64)> = runs
                    .iter()
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
fn log_range(v: impl Iterator<Item = f64>) -> (f64, f64) {
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

#[cfg(test)]
mod tests {
    use super::*;

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
}
