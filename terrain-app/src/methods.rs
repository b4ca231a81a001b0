//! Every LOD method the engine has, behind one name: what it needs precomputed for a terrain
//! ([`MethodScene`]), its per-frame selection, and the conversion of a selection into the
//! renderer's [`DrawPatch`]es.
//!
//! Methods (the names are those of the CLI and the benchmark):
//! - `uniform`: every leaf-sized patch at one factor (a baseline, no LOD).
//! - `pvps-a`, `pvps-b`, `pvps-c`: the PVPS paper's (Zhang 2021) methods A (Zhai; our documented
//!   stand-in, Röttger's d2), B (Dong: height range) and C (Eq. 5 roughness), all through the
//!   Eq. 8 split, Algorithm 1 outer levels and Eq. 12 inner levels, without occlusion culling.
//! - `dss-1`, `dss-2`: the DSS paper's (Zhang 2019) comparison Methods I (power-of-two factors)
//!   and II (uniform blocks with continuous factors).
//! - `entropy`: the entropy paper's (Chen 2018) view-dependent quadtree cut (Eq. 4-5), a
//!   triangle mesh rather than patches ([`crate::entropy_method`]): its `select` is a
//!   whole-terrain placeholder; the benchmark measures its mesh on the CPU.
//! - `geomorph`: the geomorphing article's (Wagner 2003) geo-mipmapped patches of
//!   `leaf_cells` cells with continuous tween factors, drawn by terrain-gpu's
//!   `GeomorphRenderer` (its own pipeline: [`MethodScene::select_geomorph`] and
//!   [`crate::method::GeomorphMethod`]). Through [`MethodScene::select`] (the tessellation renderer's path: `render`, `fly`,
//!   `mesh`) it gives each patch its level's factor `leaf_cells / 2^level` per edge (the shared
//!   edge at the coarser side's level): the un-morphed geo-mipmap, crack-free.
//! - `pvps-c-pvs`, `pvps-c-cons`: method C complete, with the PVS occlusion culling of section
//!   2.3.3 (terrain-visibility's `pvs`): the paper's sampled PVS, or the conservative one.
//!   Quadtree node `(l, i, j)` reads pyramid level `min(l, L)` (a node below the patch level
//!   reads its ancestor): both index the same root square, so the mapping is exact whatever the
//!   quadtree's leaf size. A camera outside every cell (`Cell_other`) culls nothing.
//! - `dss-strips`: the DSS paper's own method: M-blocks with their own continuous factors,
//!   P-blocks and dynamic stitching strips (drawn as extra triangles; see [`MethodFrame`]).
//! - `ooc`: the out-of-core paper's (Qiu 2013) method over a baked store. It is stateful (a
//!   streaming runtime and pages), so it lives in [`crate::ooc::OocScene`], not here:
//!   [`MethodScene::select`] returns an empty selection for it; [`crate::method::OocMethod`]
//!   drives it.
//!
//! - `tin`: our own method, an error-bounded TIN pyramid on the grid's quadtree
//!   (`terrain_core::tin::grid`, [`crate::method::TinMethod`]): a triangle mesh like
//!   `entropy`; [`MethodScene::select`] gives its tiles as patches (what the measurement
//!   counts as covered).
//!
//! Every method behind one per-frame interface (what `render`, `fly` and `bench` call) is
//! [`crate::method::Method`]; this module is what the in-memory methods precompute and select.

use std::sync::OnceLock;

use crate::entropy_method::{EntropyMethodConfig, EntropyScene, whole_terrain_selection};
use terrain_core::lod::{GeomipConfig, GeomipRuns, GeomipScene, GeomipSelection};
use terrain_core::quadtree::NodeId;
use terrain_gpu::geomorph::{
    GpuMorphPatch, MeshLibrary, MorphGrid, build_surface as morph_surface,
};

use terrain_core::Heightmap;
use terrain_core::geometry::Camera;
use terrain_core::lod::{
    DssConfig, DssErrorTable, DssStripsConfig, GridSource, MAX_FACTOR, MIN_FACTOR, Patch,
    PvpsConfig, Selection, SelectionStats, StripFactors, SurfaceMesh, build_surface,
    select_dss_power_of_two, select_dss_strips, select_dss_uniform, select_pvps,
    select_pvps_with_cull,
};
use terrain_core::quadtree::{FrustumCull, NodeTree, Quadtree, SplitToLevel, Visit, walk};
use terrain_core::tin::grid::GridTinPyramid;
use terrain_gpu::render::{DrawPatch, ExtraTriangles};
use terrain_gpu::strips::{self, StripMesh};
use terrain_gpu::tess::{PatchFactors, tessellate};
use terrain_visibility::pvs::{Pvs, PvsConfig, PvsMode, bake_both};
use terrain_visibility::roughness::{
    NodePyramid, RoughnessConfig, RoughnessTables, d2_pyramid, range_pyramid, roughness_pyramid,
};

/// A LOD method, by its CLI name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum LodMethod {
    /// Every leaf patch at one factor: no LOD.
    Uniform,
    /// PVPS paper method A (Zhai 2016; Röttger's d2 roughness as our documented stand-in).
    PvpsA,
    /// PVPS paper method B (Dong 2017: max - min height).
    PvpsB,
    /// PVPS paper method C (Zhang 2021: Eq. 5 roughness), without occlusion culling.
    PvpsC,
    /// DSS paper Method I: quadtree with power-of-two tessellation factors.
    #[value(name = "dss-1")]
    #[serde(rename = "dss-1")]
    Dss1,
    /// DSS paper Method II: uniform blocks with continuous factors (Eq. 4).
    #[value(name = "dss-2")]
    #[serde(rename = "dss-2")]
    Dss2,
    /// Entropy paper (Chen 2018): the local-curvature-entropy quadtree cut by Eq. 5.
    Entropy,
    /// Geomorphing article (Wagner 2003): geo-mipmapped patches morphed in the vertex shader.
    Geomorph,
    /// PVPS paper method C complete: with occlusion culling by the paper's sampled PVS.
    #[value(name = "pvps-c-pvs")]
    #[serde(rename = "pvps-c-pvs")]
    PvpsCPvs,
    /// Method C with occlusion culling by the conservative PVS (never culls a visible patch).
    #[value(name = "pvps-c-cons")]
    #[serde(rename = "pvps-c-cons")]
    PvpsCConservative,
    /// DSS paper's own method: continuous factors per M-block, stitching strips and P-blocks.
    #[value(name = "dss-strips")]
    #[serde(rename = "dss-strips")]
    DssStrips,
    /// `dss-strips` with each block's factor rounded up to a power of two (not the paper's:
    /// issue 17's test of whether the sliding continuous factors make the strips pop).
    #[value(name = "dss-strips-pow2")]
    #[serde(rename = "dss-strips-pow2")]
    DssStripsPow2,
    /// The out-of-core paper's method (Qiu 2013): blocks from a store through the streamer,
    /// Eq. 7 screen error with threshold --tau (needs a store from `terrain bake`).
    #[value(name = "ooc")]
    #[serde(rename = "ooc")]
    OutOfCore,
    /// Our own method: an error-bounded TIN pyramid on the grid's quadtree, tiles chosen by
    /// Cesium's screen-space error against --tau-px (terrain-core's grid TIN pyramid).
    Tin,
    /// Geomorphing article's Table 1 "static LOD": geomorph's patches with tweening off
    /// (integer levels), drawn at their true heights by the geomorph renderer.
    #[value(name = "geomorph-static")]
    #[serde(rename = "geomorph-static")]
    GeomorphStatic,
    /// Geomorphing article's Table 1 "software morphing": geomorph's levels and tweens, every
    /// vertex morphed on the CPU each frame and uploaded, drawn without the shader's morph.
    #[value(name = "geomorph-cpu")]
    #[serde(rename = "geomorph-cpu")]
    GeomorphCpu,
    /// Geomorphing article's PVS step: `geomorph` (morphed in the vertex shader) without the
    /// patches the conservative PVS proves hidden from the camera's view cell.
    #[value(name = "geomorph-pvs")]
    #[serde(rename = "geomorph-pvs")]
    GeomorphPvs,
}

impl LodMethod {
    /// Every method, in a fixed order (the benchmark's).
    pub const ALL: [LodMethod; 17] = [
        LodMethod::Uniform,
        LodMethod::PvpsA,
        LodMethod::PvpsB,
        LodMethod::PvpsC,
        LodMethod::Dss1,
        LodMethod::Dss2,
        LodMethod::Entropy,
        LodMethod::Geomorph,
        LodMethod::PvpsCPvs,
        LodMethod::PvpsCConservative,
        LodMethod::DssStrips,
        LodMethod::OutOfCore,
        LodMethod::Tin,
        LodMethod::GeomorphStatic,
        LodMethod::GeomorphCpu,
        LodMethod::GeomorphPvs,
        LodMethod::DssStripsPow2,
    ];

    /// The CLI and report name.
    pub fn name(self) -> &'static str {
        match self {
            LodMethod::Uniform => "uniform",
            LodMethod::PvpsA => "pvps-a",
            LodMethod::PvpsB => "pvps-b",
            LodMethod::PvpsC => "pvps-c",
            LodMethod::Dss1 => "dss-1",
            LodMethod::Dss2 => "dss-2",
            LodMethod::Entropy => "entropy",
            LodMethod::Geomorph => "geomorph",
            LodMethod::PvpsCPvs => "pvps-c-pvs",
            LodMethod::PvpsCConservative => "pvps-c-cons",
            LodMethod::DssStrips => "dss-strips",
            LodMethod::DssStripsPow2 => "dss-strips-pow2",
            LodMethod::OutOfCore => "ooc",
            LodMethod::Tin => "tin",
            LodMethod::GeomorphStatic => "geomorph-static",
            LodMethod::GeomorphCpu => "geomorph-cpu",
            LodMethod::GeomorphPvs => "geomorph-pvs",
        }
    }

    /// Whether the method draws extra triangles besides its patches (its selection's patches
    /// share no edges, so `lod::check_shared_edges` does not apply to it).
    pub fn has_strips(self) -> bool {
        self.strip_factors().is_some()
    }

    /// The stitching-strip methods' block factors (`dss-strips`: the paper's sliding ones;
    /// `dss-strips-pow2`: powers of two); `None` for every other method.
    pub fn strip_factors(self) -> Option<StripFactors> {
        match self {
            LodMethod::DssStrips => Some(StripFactors::Sliding),
            LodMethod::DssStripsPow2 => Some(StripFactors::PowerOfTwo),
            _ => None,
        }
    }

    /// Whether the method draws the geomorphing article's geo-mipmapped patches: its three
    /// Table 1 paths (`geomorph`, `geomorph-static`, `geomorph-cpu`) and `geomorph-pvs`.
    pub fn is_geomorph(self) -> bool {
        matches!(
            self,
            LodMethod::Geomorph
                | LodMethod::GeomorphStatic
                | LodMethod::GeomorphCpu
                | LodMethod::GeomorphPvs
        )
    }
}

/// Settings of every method; each method reads its own part.
#[derive(Debug, Clone, PartialEq)]
pub struct MethodConfig {
    /// Cells per side of the finest patch (the PVPS paper: a 64 x 64 patch grid). Default 16.
    pub leaf_cells: u32,
    /// The PVPS methods' constants (C1..C4, Eq. 8 and 12).
    pub pvps: PvpsConfig,
    /// The DSS methods' threshold and block sizes.
    pub dss: DssConfig,
    /// The `uniform` method's factor. Default 16.
    pub uniform_factor: f32,
    /// The `entropy` method's threshold, depth and Eq. 5 constants.
    pub entropy: EntropyMethodConfig,
    /// The `geomorph` method's settings (its `patch_cells` is `leaf_cells`). Default
    /// [`GeomipConfig::default`]: a 1 pixel threshold, morphing on.
    pub geomip: GeomipConfig,
    /// The PVS bake of `pvps-c-pvs` and `pvps-c-cons` when no baked PVS is given
    /// ([`MethodScene::set_pvs`]). Default: 16 x 16 cells x 3 floors and 32 x 32 patches, a
    /// quarter of the paper's cells and patches per side, so that the in-memory bake of a
    /// benchmark run stays around a minute on a 1k DEM; `terrain bake` writes the paper's
    /// configuration into a scene (`terrain bench --scene`).
    pub pvs: PvsConfig,
    /// `dss-strips`: half the strip width in cells (`DssStripsConfig::half_width_cells`).
    /// Default 1.
    pub strip_half_width_cells: u32,
    /// `ooc`: the out-of-core runtime's settings (Eq. 7's tau, cache and page budgets), read
    /// when the method is built over a store ([`crate::method::registry::build`]).
    pub ooc: crate::ooc::OocConfig,
    /// `tin`: its screen-space error threshold and pyramid.
    pub tin: crate::method::TinConfig,
}

impl Default for MethodConfig {
    fn default() -> Self {
        let leaf_cells = 16;
        Self {
            leaf_cells,
            pvps: PvpsConfig { leaf_cells, max_level: 30, ..PvpsConfig::default() },
            dss: DssConfig {
                leaf_cells,
                uniform_block_cells: leaf_cells * 4,
                ..DssConfig::default()
            },
            uniform_factor: 16.0,
            entropy: EntropyMethodConfig::default(),
            geomip: GeomipConfig { patch_cells: leaf_cells, ..GeomipConfig::default() },
            pvs: PvsConfig { cells: (16, 16), patch_level: 5, ..PvsConfig::default() },
            strip_half_width_cells: 1,
            ooc: crate::ooc::OocConfig::default(),
            tin: crate::method::TinConfig::default(),
        }
    }
}

/// What the methods precompute for one terrain: the quadtree (min/max per node), and, on
/// first use by a method that needs them, the roughness pyramids and the DSS paper's 32
/// object-space errors per node.
#[derive(Debug)]
pub struct MethodScene {
    /// The terrain.
    pub hm: Heightmap,
    /// The shared quadtree.
    pub qt: Quadtree,
    /// Roughness per node for PVPS methods A, B, C (all on the 0-255 scale of C1, C2).
    roughness: [OnceLock<NodePyramid>; 3],
    /// The DSS paper's object-space errors per node.
    dss: OnceLock<DssErrorTable>,
    /// The entropy paper's full quadtree.
    entropy: OnceLock<EntropyScene>,
    /// The geomorph method's max-error vertices per patch and level.
    geomip: OnceLock<GeomipScene>,
    /// The geomorph method's triangle lists.
    geomorph_lib: OnceLock<MeshLibrary>,
    /// The sampled (0) and conservative (1) PVS; `None` inside: no occlusion culling.
    pvs: [OnceLock<Option<Pvs>>; 2],
    /// The `tin` method's pyramid (or why it could not be built).
    tin: OnceLock<Result<GridTinPyramid, String>>,
    /// The settings.
    pub config: MethodConfig,
}

impl MethodScene {
    /// Precomputes everything every method needs for `hm`.
    pub fn new(hm: Heightmap, config: MethodConfig) -> Self {
        let qt = Quadtree::new(&hm, config.leaf_cells.max(1));
        let config = MethodConfig {
            pvps: PvpsConfig { leaf_cells: qt.leaf_cells(), ..config.pvps },
            dss: DssConfig { leaf_cells: qt.leaf_cells(), ..config.dss },
            ..config
        };
        Self {
            hm,
            qt,
            roughness: Default::default(),
            dss: OnceLock::new(),
            entropy: OnceLock::new(),
            geomip: OnceLock::new(),
            geomorph_lib: OnceLock::new(),
            pvs: Default::default(),
            tin: OnceLock::new(),
            config,
        }
    }

    /// The terrain as the methods' selections read it (the heightmap and its quadtree).
    pub fn source(&self) -> GridSource<'_> {
        GridSource::new(&self.qt, &self.hm)
    }

    /// Roughness of PVPS method A (0), B (1) or C (2), computed on first use.
    fn roughness(&self, k: usize) -> &NodePyramid {
        self.roughness[k].get_or_init(|| {
            let levels = self.qt.max_level() as usize + 1;
            match k {
                0 => d2_pyramid(&self.hm, levels).normalized_255(),
                1 => range_pyramid(&self.hm, levels).normalized_255(),
                _ => roughness_pyramid(&self.hm, levels, &RoughnessConfig::default()),
            }
        })
    }

    /// Uses the roughness pyramids `tables` (read from a scene's `roughness.bin`, see
    /// [`crate::roughness_scene`]) for PVPS methods A, B and C instead of computing them.
    /// Returns false, and sets nothing, when the tables have another level count than this
    /// scene's quadtree; a pyramid already computed or set is kept.
    pub fn set_roughness(&self, tables: RoughnessTables) -> bool {
        if tables.levels() != self.qt.max_level() as usize + 1 {
            return false;
        }
        let mut all = true;
        for (slot, p) in self.roughness.iter().zip(tables.into_array()) {
            all &= slot.set(p).is_ok();
        }
        all
    }

    /// The DSS paper's object-space errors: the table given to [`MethodScene::set_dss_errors`]
    /// (read from a scene), or computed on every core on first use.
    pub fn dss_errors(&self) -> &DssErrorTable {
        self.dss.get_or_init(|| crate::dss_scene::compute(&self.hm, &self.qt, false))
    }

    /// Uses `table` (read from a scene, see [`crate::dss_scene`]) instead of computing the DSS
    /// errors. Returns false (and keeps the first) if a table was already set or computed.
    pub fn set_dss_errors(&self, table: DssErrorTable) -> bool {
        self.dss.set(table).is_ok()
    }

    /// The entropy paper's full quadtree, built on first use.
    pub fn entropy_scene(&self) -> &EntropyScene {
        self.entropy.get_or_init(|| EntropyScene::new(&self.hm, &self.config.entropy))
    }

    /// The `tin` method's pyramid, built on every core on first use (with
    /// `config.tin.pyramid` as it is then).
    pub fn tin_pyramid(&self) -> anyhow::Result<&GridTinPyramid> {
        let built = self.tin.get_or_init(|| {
            crate::method::build_tin_pyramid(&self.hm, &self.config.tin.pyramid)
                .map_err(|e| e.to_string())
        });
        built.as_ref().map_err(|e| anyhow::anyhow!("the TIN pyramid: {e}"))
    }

    /// The PVS of mode `k` (0 sampled, 1 conservative): the one given to
    /// [`MethodScene::set_pvs`], or baked with `config.pvs` on first use (both modes at once).
    pub fn pvs(&self, k: usize) -> Option<&Pvs> {
        if self.pvs[k].get().is_none() {
            let (s, c, _) = bake_both(&self.hm, &self.config.pvs);
            let _ = self.pvs[0].set(Some(s));
            let _ = self.pvs[1].set(Some(c));
        }
        self.pvs[k].get().and_then(Option::as_ref)
    }

    /// Uses `pvs` (read from a scene) for `mode` instead of baking; `None` turns occlusion
    /// culling off for that mode. A PVS baked for another grid is refused with a message and
    /// nothing is set (the caller warns; the method then runs without occlusion culling).
    /// Only effective before the PVS was first used.
    pub fn set_pvs(&self, mode: PvsMode, pvs: Option<Pvs>) -> Result<(), String> {
        let k = usize::from(mode == PvsMode::Conservative);
        if let Some(p) = &pvs
            && !p.matches(self.qt.shape())
        {
            let l = &p.layout;
            let _ = self.pvs[k].set(None);
            return Err(format!(
                "the PVS was baked for a {} x {} grid, this terrain is {} x {}: it belongs to \
                 another DEM; bake the scene again (terrain bake)",
                l.width,
                l.height,
                self.qt.width(),
                self.qt.height()
            ));
        }
        if let Some(p) = &pvs
            && !p.matches_heights(&self.hm)
        {
            let _ = self.pvs[k].set(None);
            return Err("the PVS is stale: it was baked from other heights (another DEM of the \
                 same size, an edited file, or other --nodata / --vertical-scale options); bake \
                 the scene again (terrain bake)"
                .to_string());
        }
        let _ = self.pvs[k].set(pvs);
        Ok(())
    }

    /// Computes now what `methods` will need, so the first frame's timing is the selection's only.
    pub fn prepare(&self, methods: &[LodMethod]) {
        for m in methods {
            match m {
                LodMethod::PvpsA => {
                    self.roughness(0);
                }
                LodMethod::PvpsB => {
                    self.roughness(1);
                }
                LodMethod::PvpsC => {
                    self.roughness(2);
                }
                LodMethod::Dss1
                | LodMethod::Dss2
                | LodMethod::DssStrips
                | LodMethod::DssStripsPow2 => {
                    self.dss_errors();
                }
                LodMethod::Entropy => {
                    self.entropy_scene();
                }
                LodMethod::Geomorph | LodMethod::GeomorphStatic | LodMethod::GeomorphCpu => {
                    self.geomip_scene();
                }
                LodMethod::GeomorphPvs => {
                    self.geomip_scene();
                    self.pvs(1);
                }
                LodMethod::PvpsCPvs | LodMethod::PvpsCConservative => {
                    self.roughness(2);
                    self.pvs(usize::from(*m == LodMethod::PvpsCConservative));
                }
                LodMethod::Tin => {
                    // A failure is reported when the method is built.
                    let _ = self.tin_pyramid();
                }
                LodMethod::Uniform | LodMethod::OutOfCore => {}
            }
        }
    }

    /// The patches `method` draws from `camera`, with their tessellation factors.
    pub fn select(&self, method: LodMethod, camera: &Camera) -> Selection {
        let pvps =
            |field: &NodePyramid| select_pvps(&self.source(), camera, field, &self.config.pvps);
        match method {
            LodMethod::Uniform => self.select_uniform(camera),
            LodMethod::PvpsA => pvps(self.roughness(0)),
            LodMethod::PvpsB => pvps(self.roughness(1)),
            LodMethod::PvpsC => pvps(self.roughness(2)),
            LodMethod::Dss1 => {
                select_dss_power_of_two(&self.qt, camera, self.dss_errors(), &self.config.dss)
            }
            LodMethod::Dss2 => {
                select_dss_uniform(&self.qt, camera, self.dss_errors(), &self.config.dss)
            }
            // A mesh, not patches: see `EntropyScene::frame`; the root stands for "everything".
            LodMethod::Entropy => whole_terrain_selection(1, 0.0),
            LodMethod::Geomorph
            | LodMethod::GeomorphStatic
            | LodMethod::GeomorphCpu
            | LodMethod::GeomorphPvs => {
                let mut frame =
                    self.select_geomorph_with(camera, method != LodMethod::GeomorphStatic);
                if method == LodMethod::GeomorphPvs {
                    self.cull_geomorph_pvs(&mut frame, camera);
                }
                self.geomorph_selection(&frame)
            }
            LodMethod::PvpsCPvs | LodMethod::PvpsCConservative => {
                let field = self.roughness(2);
                let k = usize::from(method == LodMethod::PvpsCConservative);
                match self.pvs(k) {
                    // Section 2.3.3: camera -> cell (or Cell_other) -> O(1) per node.
                    Some(pvs) => select_pvps_with_cull(
                        &self.source(),
                        camera,
                        field,
                        &self.config.pvps,
                        &mut pvs.cull_for(camera.position),
                    ),
                    None => pvps(field),
                }
            }
            LodMethod::DssStrips | LodMethod::DssStripsPow2 => self.frame(method, camera).selection,
            // Stateful: crate::ooc::OocScene draws it (see the module docs).
            LodMethod::OutOfCore => Selection::default(),
            // A mesh; its tiles as patches (nothing without a pyramid).
            LodMethod::Tin => match self.tin_pyramid() {
                Ok(p) => crate::method::tin_selection(&p.select(camera, self.config.tin.tau_px)),
                Err(_) => Selection::default(),
            },
        }
    }

    /// What `method` draws from `camera`: its selection and, for `dss-strips`, the blocks
    /// and the strips built this frame. The selection's `cpu_time` covers all of it (for
    /// `dss-strips`: the multilevel update plus the strip construction).
    pub fn frame(&self, method: LodMethod, camera: &Camera) -> MethodFrame {
        let Some(factors) = method.strip_factors() else {
            return MethodFrame { selection: self.select(method, camera), strips: None };
        };
        strips_frame(&self.qt, camera, self.dss_errors(), &self.config, factors, true)
    }

    /// The surface a frame draws, rebuilt on the CPU (see [`MethodScene::drawn_surface`]),
    /// strips included; and the drawn triangle count.
    pub fn frame_surface(&self, frame: &MethodFrame) -> (SurfaceMesh, u64) {
        match &frame.strips {
            None => self.drawn_surface(&frame.selection),
            Some(s) => strips::build_strip_surface(&self.hm, &s.patches, &s.mesh.triangles),
        }
    }

    /// The renderer's patches and extra triangles of a frame.
    pub fn frame_draw(&self, frame: &MethodFrame) -> (Vec<DrawPatch>, ExtraTriangles) {
        match &frame.strips {
            None => (self.draw_patches(&frame.selection), ExtraTriangles::default()),
            Some(s) => (s.patches.clone(), s.mesh.triangles.clone()),
        }
    }

    /// Patch cells of the geomorph method: the quadtree's leaf size, so its patches are the
    /// quadtree's leaves (the measurement's coverage).
    /// (The geomorph renderer supports 2 to 64 cells; other leaf sizes are clamped, and then
    /// the measurement's coverage no longer matches the patches.)
    pub fn geomorph_patch_cells(&self) -> u32 {
        self.qt.leaf_cells().clamp(2, 64)
    }

    /// The geomorph method's per-patch precomputation, on first use.
    pub fn geomip_scene(&self) -> &GeomipScene {
        self.geomip.get_or_init(|| GeomipScene::new(&self.hm, self.geomorph_patch_cells()))
    }

    /// The geomorph method's levels, tween factors and border rules for `camera`.
    pub fn select_geomorph(&self, camera: &Camera) -> GeomipSelection {
        self.select_geomorph_with(camera, self.config.geomip.morph)
    }

    /// [`MethodScene::select_geomorph`] with tweening on or off (`geomorph-static`: integer
    /// levels, every tween factor 0).
    pub fn select_geomorph_with(&self, camera: &Camera, morph: bool) -> GeomipSelection {
        let cfg =
            GeomipConfig { patch_cells: self.geomorph_patch_cells(), morph, ..self.config.geomip };
        self.geomip_scene().select(camera, &cfg)
    }

    /// The geomorph method's selection, compact: runs of patches at the coarsest level and
    /// the others one by one ([`terrain_core::lod::GeomipTable::select_runs`]); its
    /// expansion is [`MethodScene::select_geomorph_with`].
    pub fn select_geomorph_runs(&self, camera: &Camera, morph: bool) -> GeomipRuns {
        let cfg =
            GeomipConfig { patch_cells: self.geomorph_patch_cells(), morph, ..self.config.geomip };
        self.geomip_scene().select_runs(camera, &cfg)
    }

    /// `geomorph-pvs`: removes from `frame` the patches that the conservative PVS proves hidden
    /// from the camera's view cell, and counts them as culled. This is the geomorphing
    /// article's third culling step (its "PVS" section: after the ground rectangle and the
    /// frustum, the patches hidden by other patches), with our conservative bake in place of
    /// its line-of-sight samples, so that no visible patch is removed (the sampled bake culls
    /// some; terrain-visibility's `pvs` module docs). The remaining patches keep their levels,
    /// tween factors and border rules, so they join each other as in `geomorph`. Nothing is
    /// removed without a PVS or when the camera is in `Cell_other` (outside the cells or above
    /// the top floor).
    pub fn cull_geomorph_pvs(&self, frame: &mut GeomipSelection, camera: &Camera) {
        let Some(pvs) = self.pvs(1) else { return };
        let Some(cell) = pvs.cull_for(camera.position).cell else { return };
        // A patch of `n` cells is a node of the scene's quadtree (leaves of `leaf_cells`),
        // `log2(leaf_cells / n)` levels below its leaves; the PVS reads a deeper node's ancestor.
        let n = self.geomorph_patch_cells();
        let leaf = self.qt.leaf_cells().max(1);
        let level = (i32::from(self.qt.max_level()) + leaf.trailing_zeros() as i32
            - n.trailing_zeros() as i32)
            .clamp(0, 31) as u8;
        let before = frame.patches.len();
        let keep: Vec<bool> =
            frame.patches.iter().map(|p| pvs.visible(cell, NodeId::new(level, p.i, p.j))).collect();
        // `retain` visits the elements once each, in order; `factors` is parallel to `patches`.
        let mut k = keep.iter().copied();
        frame.patches.retain(|_| k.next() == Some(true));
        let mut k = keep.iter().copied();
        frame.factors.retain(|_| k.next() == Some(true));
        frame.culled += before - frame.patches.len();
    }

    /// The geomorph patches as a quadtree [`Selection`] of leaves, each edge's factor
    /// `leaf_cells / 2^(edge level)` and the inner factors `leaf_cells / 2^level`: what the
    /// measurement's coverage and the tessellation renderer read.
    pub fn geomorph_selection(&self, frame: &GeomipSelection) -> Selection {
        geomorph_selection(frame, self.geomorph_patch_cells(), self.qt.max_level())
    }

    /// [`MethodScene::geomorph_selection`] of a compact selection ([`geomorph_selection_runs`]).
    pub fn geomorph_selection_runs(&self, runs: &GeomipRuns) -> Selection {
        geomorph_selection_runs(runs, self.geomorph_patch_cells(), self.qt.max_level())
    }

    /// The surface the geomorph renderer draws for `frame` (the morph's CPU reference, the
    /// same numbers as the vertex stage) and its non-degenerate triangles.
    pub fn geomorph_surface(&self, frame: &GeomipSelection) -> (SurfaceMesh, u64) {
        let n = self.geomorph_patch_cells();
        let grid = MorphGrid::new(&self.hm, n);
        let lib = self.geomorph_library();
        let patches: Vec<GpuMorphPatch> =
            frame.patches.iter().map(|p| GpuMorphPatch::from_lod(p, n)).collect();
        morph_surface(&grid, lib, &patches)
    }

    fn geomorph_library(&self) -> &MeshLibrary {
        self.geomorph_lib.get_or_init(|| MeshLibrary::new(self.geomorph_patch_cells()))
    }

    /// Every finest-level patch inside the frustum, every factor `uniform_factor`.
    fn select_uniform(&self, camera: &Camera) -> Selection {
        select_uniform(&self.qt, camera, self.config.uniform_factor)
    }

    /// The surface a selection draws, rebuilt on the CPU with the tessellator's CPU reference
    /// (bit-identical to the GPU's): what the benchmark measures and `terrain mesh --camera`
    /// exports. Also returns the non-degenerate triangle count, as the renderer counts them.
    pub fn drawn_surface(&self, selection: &Selection) -> (SurfaceMesh, u64) {
        drawn_surface_of(&self.hm, &self.qt, selection)
    }

    /// The renderer's patches for a selection (see [`draw_patches`]).
    pub fn draw_patches(&self, selection: &Selection) -> Vec<DrawPatch> {
        draw_patches(&self.qt, selection)
    }
}

/// Every finest-level patch in the frustum at one factor: the `uniform` method over any node
/// tree (a heightmap's quadtree, a store's).
pub fn select_uniform(src: &dyn NodeTree, camera: &Camera, factor: f32) -> Selection {
    let start = std::time::Instant::now();
    let mut cull = FrustumCull::new(camera.frustum());
    let max = src.shape().max_level();
    // Through the traversal's node source: a store's looks each block up once per run of its
    // nodes, not once per node.
    // Patches listed as the walk reports their leaves: no list of leaves beside them (3.8 M
    // patches at 1 px over a 32769^2 store).
    let f = factor.clamp(MIN_FACTOR, MAX_FACTOR);
    let mut patches = Vec::new();
    src.with_traversal_source(&mut |nodes| {
        walk(nodes, &mut SplitToLevel(max), &mut cull, &mut |node, visit| {
            if visit == Visit::Leaf {
                patches.push(Patch { node, outer: [f; 4], inner: [f; 2] });
            }
        });
    });
    let stats = SelectionStats {
        traversal_leaves: patches.len(),
        patches: patches.len(),
        max_level: max,
        cpu_time: start.elapsed(),
        ..SelectionStats::default()
    };
    Selection { patches, stats }
}

/// The DSS paper's strip method's configuration from the shared method configuration.
fn strips_config(config: &MethodConfig, factors: StripFactors) -> DssStripsConfig {
    DssStripsConfig {
        dss: config.dss.clone(),
        half_width_cells: config.strip_half_width_cells,
        factors,
    }
}

/// The `dss-strips` frame over any node tree (a heightmap's quadtree, a store's): the
/// multilevel update, the strips and P-blocks built this frame (`build`; else an empty mesh,
/// for a selection that is not drawn: the store's demand for the eye ahead, Eq. 8, reads only
/// which blocks the strips line), the blocks as draw patches. The selection's `cpu_time`
/// covers the update and the strip construction; `factors` is the method's
/// ([`LodMethod::strip_factors`]).
pub fn strips_frame(
    src: &dyn NodeTree,
    camera: &Camera,
    table: &DssErrorTable,
    config: &MethodConfig,
    factors: StripFactors,
    build: bool,
) -> MethodFrame {
    let frame = select_dss_strips(src, camera, table, &strips_config(config, factors));
    let update = frame.stats.cpu_time;
    let mesh = if build { strips::build_strips(&frame) } else { StripMesh::default() };
    let mut selection = frame.selection();
    selection.stats.cpu_time = update + mesh.cpu_time;
    let patches = strips::draw_patches(&frame);
    let nodes = frame.blocks.iter().map(|b| b.node).collect();
    let lined = frame.lined_blocks();
    MethodFrame { selection, strips: Some(StripFrame { patches, nodes, lined, mesh, update }) }
}

/// What a method draws in one frame ([`MethodScene::frame`]).
#[derive(Debug, Clone)]
pub struct MethodFrame {
    /// The selection: drawn patches (for `dss-strips`, its visible M-blocks).
    pub selection: Selection,
    /// `dss-strips` only: the blocks as draw patches and the strips.
    pub strips: Option<StripFrame>,
}

/// The `dss-strips` part of a [`MethodFrame`].
#[derive(Debug, Clone)]
pub struct StripFrame {
    /// Every M-block (hidden ones with outer factors 0), the strips' patch indices.
    pub patches: Vec<DrawPatch>,
    /// The quadtree node of each of `patches`.
    pub nodes: Vec<NodeId>,
    /// Whether a strip or P-block vertex lies on each of `patches`
    /// ([`DssStripFrame::lined_blocks`]).
    pub lined: Vec<bool>,
    /// Strips and P-blocks, with their construction time.
    pub mesh: StripMesh,
    /// The multilevel update's time (section 3.3.1).
    pub update: std::time::Duration,
}

/// [`MethodScene::drawn_surface`] over any heights `hm` of `qt`'s grid (the out-of-core method
/// draws its pages' heights, not the full DEM's).
pub fn drawn_surface_of(
    hm: &Heightmap,
    qt: &Quadtree,
    selection: &Selection,
) -> (SurfaceMesh, u64) {
    let triangles = std::cell::Cell::new(0u64);
    let mesh = build_surface(hm, qt, selection, |p: &Patch| {
        let m = tessellate(&patch_factors(p));
        triangles.set(triangles.get() + m.non_degenerate_triangle_count() as u64);
        let tris = m.indices.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        (m.points, tris)
    });
    (mesh, triangles.get())
}

/// Converts a selection into the renderer's patches.
///
/// The rect is the node's *unclipped* square (it may reach past the grid's east and north
/// border, where the renderer clamps domain points to the grid, exactly as
/// `terrain_core::lod::surface::patch_grid_point` does), so vertices that coincide in the full
/// quadtree coincide at the border too. Outer factors move from the selection's
/// [south, east, north, west] to the tessellator's Vulkan order [west, south, east, north].
pub fn draw_patches(qt: &Quadtree, selection: &Selection) -> Vec<DrawPatch> {
    selection
        .patches
        .iter()
        .map(|p| {
            let (x0, y0, c) = p.node.grid_rect(qt.root_cells());
            DrawPatch { rect: [x0, y0, x0 + c, y0 + c], factors: patch_factors(p) }
        })
        .collect()
}

/// The tessellator's factors of a selected patch: outer factors move from the selection's
/// [south, east, north, west] to Vulkan's [west, south, east, north].
pub fn patch_factors(p: &Patch) -> PatchFactors {
    let [s, e, n, w] = p.outer;
    PatchFactors { inner: p.inner, outer: [w, s, e, n] }
}

/// Geomorph patches (`frame`) of `patch_cells` cells as a quadtree [`Selection`] of the leaves
/// at level `leaf_level` of the patch tree, each edge's factor `patch_cells / 2^(edge level)`
/// and the inner factors `patch_cells / 2^level`: the un-morphed geo-mipmap as tessellated
/// patches (what the measurement's coverage and the tessellation and paged renderers read),
/// from memory or from a store.
pub fn geomorph_selection(frame: &GeomipSelection, patch_cells: u32, leaf_level: u8) -> Selection {
    geomorph_leaves(
        frame.patches.iter().copied(),
        patch_cells,
        leaf_level,
        frame.culled,
        frame.cpu_ms,
    )
}

/// [`geomorph_selection`] of a compact selection: the same [`Selection`] as of its expansion
/// ([`GeomipRuns::expand`]), built from the runs' patches and the single ones without the
/// expanded list (`cpu_time` the selection's own, `runs.cpu_ms`).
pub fn geomorph_selection_runs(runs: &GeomipRuns, patch_cells: u32, leaf_level: u8) -> Selection {
    let in_runs = runs.runs.iter().flat_map(|r| {
        (r.j..r.j + r.height).flat_map(move |j| (r.i..r.i + r.width).map(move |i| (i, j)))
    });
    let all = runs.patches.iter().copied().chain(in_runs.map(|(i, j)| runs.run_patch(i, j)));
    geomorph_leaves(all, patch_cells, leaf_level, runs.culled, runs.cpu_ms)
}

/// Geomorph's patch `p` (of `patch_cells` cells) as a leaf of the patch tree (level
/// `leaf_level`) with the factors of its un-morphed geo-mipmap: its level's inside, its edge
/// levels' edges (what the coverage counts and what the streamer's demand reads).
pub fn geomorph_patch(p: &terrain_core::lod::PatchLod, patch_cells: u32, leaf_level: u8) -> Patch {
    let n = patch_cells as f32;
    let f = |l: u8| (n / f32::from(1u8 << l)).clamp(MIN_FACTOR, MAX_FACTOR);
    Patch {
        node: NodeId::new(leaf_level, p.i, p.j),
        outer: p.edge_level.map(f),
        inner: [f(p.level); 2],
    }
}

fn geomorph_leaves(
    lods: impl Iterator<Item = terrain_core::lod::PatchLod>,
    patch_cells: u32,
    leaf_level: u8,
    culled: usize,
    cpu_ms: f64,
) -> Selection {
    let mut patches: Vec<Patch> =
        lods.map(|p| geomorph_patch(&p, patch_cells, leaf_level)).collect();
    // Keys are distinct: one key computation per patch, same order as a stable sort.
    patches.sort_by_cached_key(|p| p.node.dfs_key());
    let stats = SelectionStats {
        traversal_leaves: patches.len(),
        patches: patches.len(),
        culled,
        max_level: leaf_level,
        cpu_time: std::time::Duration::from_secs_f64(cpu_ms / 1e3),
        ..SelectionStats::default()
    };
    Selection { patches, stats }
}

#[cfg(test)]
mod tests {
    use super::*;
    use terrain_core::lod::check_shared_edges;
    use terrain_core::synth::FractalConfig;
    use terrain_gpu::render::crack::crack_cameras;

    /// The geomorph method through the common path: its leaves agree on every shared edge's
    /// factor (so `render`/`fly` draw it without cracks), cover what its own surface covers,
    /// and that surface is watertight.
    /// `geomorph-pvs` draws geomorph's patches minus those the conservative PVS hides, each
    /// with its level and tween unchanged, and counts the removed ones as culled; on the
    /// crack-test cameras some patch is hidden (else the test could not tell culling from none).
    #[test]
    fn geomorph_pvs_draws_a_subset_of_geomorph_and_hides_some() {
        let hm = FractalConfig::with_size(257, 257, 10.0).to_heightmap().unwrap();
        let scene = MethodScene::new(hm, MethodConfig::default());
        let mut hidden = 0;
        for camera in crack_cameras(&scene.hm, 17) {
            let camera = camera.with_viewport(1280.0, 720.0);
            let all = scene.select_geomorph(&camera);
            let mut some = all.clone();
            scene.cull_geomorph_pvs(&mut some, &camera);
            assert_eq!(some.patches.len(), some.factors.len());
            for (p, f) in some.patches.iter().zip(&some.factors) {
                let k = all.patches.iter().position(|q| q == p).expect("a patch geomorph draws");
                assert_eq!(all.factors[k], *f);
            }
            assert_eq!(some.culled - all.culled, all.patches.len() - some.patches.len());
            hidden += all.patches.len() - some.patches.len();
            let selection = scene.geomorph_selection(&some);
            assert!(check_shared_edges(&selection).is_empty());
        }
        assert!(hidden > 0, "no patch was hidden from any camera");
    }

    #[test]
    fn geomorph_selection_agrees_on_shared_edges() {
        let hm = FractalConfig::with_size(257, 257, 10.0).to_heightmap().unwrap();
        let scene = MethodScene::new(hm, MethodConfig::default());
        for camera in crack_cameras(&scene.hm, 17).iter().step_by(4) {
            let camera = camera.with_viewport(1280.0, 720.0);
            let frame = scene.select_geomorph(&camera);
            let selection = scene.geomorph_selection(&frame);
            assert_eq!(selection.patches.len(), frame.patches.len());
            assert!(check_shared_edges(&selection).is_empty());
            let (mesh, triangles) = scene.geomorph_surface(&frame);
            assert!(triangles > 0);
            assert!(mesh.positions.iter().all(|p| p.z.is_finite()));
        }
    }
}
