//! Every LOD method the engine has, behind one name: what it needs precomputed for a terrain
//! ([`MethodScene`]), its per-frame selection, and the conversion of a selection into the
//! renderer's [`DrawPatch`]es.
//!
//! Methods (the names are those of the CLI and the benchmark):
//! - `uniform`: every leaf-sized patch at one factor (a baseline, no LOD).
//! - `pvps-a`, `pvps-b`, `pvps-c`: the PVPS paper's (Zhang 2021) methods A (Zhai; our documented
//!   stand-in, Röttger's d2), B (Dong: height range) and C (Eq. 5 roughness), all through the
//!   Eq. 8 split, Algorithm 1 outer levels and Eq. 12 inner levels (occlusion culling is the
//!   occlusion issue's).
//! - `dss-1`, `dss-2`: the DSS paper's (Zhang 2019) comparison Methods I (power-of-two factors)
//!   and II (uniform blocks with continuous factors).
//! - `ooc`: the out-of-core paper's (Qiu 2013) method over a baked store. It is stateful (a
//!   streaming runtime and pages), so it lives in [`crate::ooc::OocScene`], not here:
//!   [`MethodScene::select`] returns an empty selection for it, and the benchmark and
//!   `terrain render <store>` drive it.

use std::sync::OnceLock;

use terrain_core::Heightmap;
use terrain_core::geometry::Camera;
use terrain_core::lod::{
    DssConfig, DssErrorTable, MAX_FACTOR, MIN_FACTOR, Patch, PvpsConfig, Selection, SelectionStats,
    SurfaceMesh, build_surface, select_dss_power_of_two, select_dss_uniform, select_pvps,
};
use terrain_core::quadtree::{FrustumCull, Quadtree, SplitToLevel, select};
use terrain_gpu::render::DrawPatch;
use terrain_gpu::tess::{PatchFactors, tessellate};
use terrain_visibility::roughness::{
    NodePyramid, RoughnessConfig, d2_pyramid, range_pyramid, roughness_pyramid,
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
    /// The out-of-core paper's method (Qiu 2013): blocks from a store through the streamer,
    /// Eq. 7 screen error with threshold tau ([`crate::ooc`]).
    #[value(name = "ooc")]
    #[serde(rename = "ooc")]
    OutOfCore,
}

impl LodMethod {
    /// Every method, in a fixed order (the benchmark's).
    pub const ALL: [LodMethod; 7] = [
        LodMethod::Uniform,
        LodMethod::PvpsA,
        LodMethod::PvpsB,
        LodMethod::PvpsC,
        LodMethod::Dss1,
        LodMethod::Dss2,
        LodMethod::OutOfCore,
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
            LodMethod::OutOfCore => "ooc",
        }
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
        Self { hm, qt, roughness: Default::default(), dss: OnceLock::new(), config }
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

    /// The DSS paper's object-space errors, computed on first use.
    pub fn dss_errors(&self) -> &DssErrorTable {
        self.dss.get_or_init(|| DssErrorTable::new(&self.hm, &self.qt))
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
                LodMethod::Dss1 | LodMethod::Dss2 => {
                    self.dss_errors();
                }
                LodMethod::Uniform | LodMethod::OutOfCore => {}
            }
        }
    }

    /// The patches `method` draws from `camera`, with their tessellation factors.
    pub fn select(&self, method: LodMethod, camera: &Camera) -> Selection {
        let pvps =
            |field: &NodePyramid| select_pvps(&self.qt, &self.hm, camera, field, &self.config.pvps);
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
            // Stateful: crate::ooc::OocScene draws it (see the module docs).
            LodMethod::OutOfCore => Selection::default(),
        }
    }

    /// Every finest-level patch inside the frustum, every factor `uniform_factor`.
    fn select_uniform(&self, camera: &Camera) -> Selection {
        let start = std::time::Instant::now();
        let mut cull = FrustumCull::new(camera.frustum());
        let leaves = select(&self.qt, &mut SplitToLevel(self.qt.max_level()), &mut cull);
        let f = self.config.uniform_factor.clamp(MIN_FACTOR, MAX_FACTOR);
        let patches: Vec<Patch> =
            leaves.iter().map(|&node| Patch { node, outer: [f; 4], inner: [f; 2] }).collect();
        let stats = SelectionStats {
            traversal_leaves: patches.len(),
            patches: patches.len(),
            max_level: self.qt.max_level(),
            cpu_time: start.elapsed(),
            ..SelectionStats::default()
        };
        Selection { patches, stats }
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
