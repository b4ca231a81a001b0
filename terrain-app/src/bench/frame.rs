//! One benchmark frame: [`FrameRunner`] selects, rebuilds the drawn surface on the CPU,
//! measures and optionally renders; [`entropy_extra`] turns the entropy mesh into the
//! renderer's extra triangles.

use std::time::Instant;

use terrain_core::Heightmap;
use terrain_core::geometry::Camera;
use terrain_core::lod::SurfaceMesh;
use terrain_core::measure::{MeasureConfig, Measurer};
use terrain_gpu::geomorph::{GeomorphOptions, GeomorphRenderer, max_vertex_jump};
use terrain_gpu::render::{DrawPatch, ExtraTriangles};
use terrain_gpu::tess::{GpuDomainPoint, GpuPatchFactors, PatchRange};
use terrain_gpu::{RenderOptions, TerrainRenderer};

use super::record::{FrameRecord, rss_bytes};
use crate::entropy_method::whole_terrain_selection;
use crate::methods::{LodMethod, MethodScene};

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

pub(super) fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}
