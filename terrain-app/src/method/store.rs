//! The in-memory patch methods drawn from a baked store: `uniform`, `pvps-a/b/c` (with or
//! without the PVS: `pvps-c-pvs`, `pvps-c-cons`), `dss-1`, `dss-2`, `dss-strips` (its
//! M-blocks, P-blocks and stitching strips) and `geomorph` (its geo-mipmapped patches with
//! their levels and tween factors, morphed in the vertex shader) select their patches
//! with the same terrain-core functions as from memory, over the store's terrain
//! (terrain-stream's `StoreSource`: node bounds from the index, heights from the resident
//! levels) and the per-node tables the bake wrote beside the blocks (`dss_errors.bin`,
//! `roughness.bin`, `geomip.bin`, the PVS files). The store's runtime ([`OocScene::frame_for`])
//! loads what the patches need (geomorph: each patch's level, as its un-morphed geo-mipmap
//! says, computed from the runs' rectangles and the single patches without expanding them,
//! [`crate::ooc::morph_demand`]; the morph only reads vertices of that level and coarser) and the paged renderer draws them, or, for
//! geomorph, terrain-gpu's `GeomorphRenderer` in paged mode reads the paged renderer's pages
//! through the same lookup and draws the runs without expanding them; nothing of the full grid is in
//! memory. A warm frame (`--wait`, and the first frame) selects the patches the method selects
//! from the heightmap in memory (tested patch for patch, and geomorph's morphed heights vertex
//! for vertex).
//!
//! A store opened exaggerated ([`terrain_stream::Store::exaggerated`], `--vertical-scale`)
//! is the terrain of the heights times the exaggeration: its heights and index errors are
//! scaled as read, and so are the object-space tables read here (DSS's errors and geomorph's
//! max-error vertices, vertical distances: `exaggerated`); the PVS, a visibility relation,
//! is invariant under the vertical scaling (an affine map keeps sight lines), so the eye is
//! looked up at its unexaggerated height. PVPS's roughness (Eq. 5, `1 / cos(slope)`,
//! normalised) is not linear in the heights: it is read as baked, so an exaggerated PVPS
//! selection differs from PVPS over the exaggerated DEM in memory.
//!
//! Not from a store yet: `entropy` (a mesh of the whole grid): [`store_method`] says so.

use std::path::Path;

use anyhow::Context;
use terrain_core::Heightmap;
use terrain_core::geometry::Camera;
use terrain_core::lod::{
    DssErrorTable, GeomipConfig, GeomipTable, TerrainSource, select_dss_power_of_two,
    select_dss_uniform, select_pvps, select_pvps_with_cull,
};
use terrain_core::lod::{Selection, SelectionStats};
use terrain_core::quadtree::NodeTree;
use terrain_gpu::geomorph::{
    GpuMorphPatch, MeshLibrary, MorphGrid, build_surface, max_vertex_jump,
};
use terrain_stream::{StoreSource, StoreTree};
use terrain_visibility::pvs::{Pvs, PvsMode, read_pvs};
use terrain_visibility::roughness::NodePyramid;

use super::ooc::{OocWait, drawn_heights, mirrored, paged_frame, paged_surface};
use super::{Draw, DrawSource, DrawnSurface, Frame, Method, OocMethod};
use crate::methods::{
    LodMethod, MethodConfig, MethodScene, geomorph_selection_runs, select_uniform, strips_frame,
};
use crate::ooc::{MorphDraw, OocScene, StoreDraw};

/// Which methods draw from a store.
pub fn draws_from_store(kind: LodMethod) -> bool {
    // geomorph-static and geomorph-cpu (the article's Table 1 comparison) and geomorph-pvs
    // (its PVS step) draw from memory; tin draws its tiles from the store.
    kind == LodMethod::Tin
        || !(super::registry::draws_mesh(kind)
            || matches!(
                kind,
                LodMethod::GeomorphStatic | LodMethod::GeomorphCpu | LodMethod::GeomorphPvs
            ))
}

/// `kind` over the store of `scene` (its runtime), with `config`'s parameters; measured
/// against `reference` (the same DEM in memory) when given. `ooc` is the out-of-core paper's
/// own method ([`OocMethod`]); the others read their tables from the store folder and fail
/// with what to bake when one is missing. The method is `Send`: `terrain view` builds it (and
/// plays its first, waiting frame) on a worker thread.
pub fn store_method<'a>(
    kind: LodMethod,
    scene: OocScene,
    config: &MethodConfig,
    wait: OocWait,
    reference: Option<&'a MethodScene>,
) -> anyhow::Result<Box<dyn Method + Send + 'a>> {
    if kind == LodMethod::OutOfCore {
        return Ok(match reference {
            Some(r) => Box::new(OocMethod::measured(scene, r, wait)?),
            None => Box::new(OocMethod::new(scene, wait)),
        });
    }
    if kind == LodMethod::Tin {
        let scene = runtime_for(scene, wait, reference.is_some());
        return Ok(Box::new(super::TinStoreMethod::new(scene, &config.tin, wait, reference)?));
    }
    if !draws_from_store(kind) {
        anyhow::bail!(
            "--method {} draws from a DEM in memory only so far; from a store use ooc, uniform, \
             pvps-a, pvps-b, pvps-c, pvps-c-pvs, pvps-c-cons, dss-1, dss-2, dss-strips, \
             geomorph or tin (or render the DEM file itself)",
            kind.name()
        );
    }
    Ok(Box::new(StoreMethod::new(kind, scene, config, wait, reference)?))
}

/// The per-node tables a store-backed method reads.
#[derive(Debug)]
enum Tables {
    None,
    Roughness(NodePyramid),
    RoughnessPvs(NodePyramid, Option<Pvs>),
    Dss(DssErrorTable),
    /// Geomorph's max-error vertices and its triangle lists (the CPU reference's).
    Geomip(GeomipTable, MeshLibrary),
}

impl Tables {
    /// A table read by pages (geomorph's or the DSS table): its pages read late so far and the
    /// bytes its cache holds now; `(0, 0)` for the others.
    fn paging(&self) -> (u64, u64) {
        match self {
            Tables::Geomip(t, _) => {
                t.paging_stats().map_or((0, 0), |s| (s.pages_late, s.cached_bytes))
            }
            Tables::Dss(t) => t.paging_stats().map_or((0, 0), |s| (s.pages_late, s.cached_bytes)),
            _ => (0, 0),
        }
    }
}

/// A patch method over a store (see the module docs).
#[derive(Debug)]
pub struct StoreMethod<'a> {
    kind: LodMethod,
    scene: OocScene,
    /// The store's tree at the method's leaf size.
    tree: StoreTree,
    tables: Tables,
    config: MethodConfig,
    reference: Option<&'a MethodScene>,
    wait: OocWait,
    frames: usize,
    /// The store's vertical exaggeration (its header's).
    vertical_scale: f64,
}

/// The error of a store-backed method whose store does not match the DEM in memory it is
/// measured against: `what` (its quadtree, its grid) differs; both sizes and roots named.
pub(super) fn not_the_reference(
    dir: &Path,
    what: &str,
    shape: &terrain_core::quadtree::TreeShape,
    r: &MethodScene,
) -> anyhow::Error {
    anyhow::anyhow!(
        "the store {} is not the {what} of the DEM it is measured against (store: {} x {} \
         samples, root {} cells; DEM: {} x {}, root {}): bake it from that DEM",
        dir.display(),
        shape.width(),
        shape.height(),
        shape.root_cells(),
        r.qt.width(),
        r.qt.height(),
        r.qt.root_cells()
    )
}

/// Checks that the store holds the heights of `hm`, the DEM it is measured against: each
/// block's stored minimum and maximum equal the DEM's over the block's samples within the
/// store's quantization bound (`Header::max_error_m`, plus a millimetre), blocks with void
/// samples skipped. A size check alone ([`not_the_reference`]) passed a DEM mirrored
/// north-south (a raw file written south row first and read north row first, as `--raw`
/// reads files): every frame was then measured against another terrain (19 px p99 on
/// `fast_pass` over the 32769^2 store, and false culls where the store's node boxes,
/// used by the frustum cull, missed the mirror's heights; bench/ooc/README.md).
pub(crate) fn check_same_heights(
    store: &terrain_stream::Store,
    hm: &Heightmap,
) -> anyhow::Result<()> {
    let h = store.header();
    let c = h.block_cells() as usize;
    // `max_error_m` is scaled with the heights when the store was opened exaggerated.
    let tol = h.max_error_m.abs() + 1e-3;
    let voids = hm.voids();
    for id in store.block_ids() {
        let Some(e) = store.entry(id) else { continue };
        let (x0, y0) = (id.col as usize * c, id.row as usize * c);
        let (x1, y1) = (x0 + e.valid_w.max(1) as usize, y0 + e.valid_h.max(1) as usize);
        if x1 > hm.width() || y1 > hm.height() {
            continue;
        }
        let (mut lo, mut hi, mut void) = (f32::INFINITY, f32::NEG_INFINITY, false);
        for y in y0..y1 {
            for x in x0..x1 {
                void |= voids.any() && voids.get(x, y);
                let z = hm.get(x, y);
                lo = lo.min(z);
                hi = hi.max(z);
            }
        }
        if void {
            continue;
        }
        let off =
            (f64::from(lo) - f64::from(e.min)).abs().max((f64::from(hi) - f64::from(e.max)).abs());
        if off > tol + 1e-6 * f64::from(hi.abs().max(lo.abs())) {
            anyhow::bail!(
                "the store {} does not hold the heights of the DEM it is measured against: block \
                 {id} stores heights {:.3}..{:.3} m, the DEM has {lo:.3}..{hi:.3} m there (a DEM \
                 mirrored or shifted against the store's? raw files are read north row first): \
                 bake the store from that DEM",
                store.dir().display(),
                e.min,
                e.max,
            );
        }
    }
    Ok(())
}

impl<'a> StoreMethod<'a> {
    fn new(
        kind: LodMethod,
        scene: OocScene,
        config: &MethodConfig,
        wait: OocWait,
        reference: Option<&'a MethodScene>,
    ) -> anyhow::Result<Self> {
        let store = scene.store().clone();
        let vertical_scale = store.header().vertical_scale;
        // Geomorph's patch tree: leaves of its patch size (the leaf size clamped to 2..=64, as
        // `MethodScene::geomorph_patch_cells`).
        let leaf_cells = match kind {
            LodMethod::Geomorph => config.leaf_cells.clamp(2, 64).next_power_of_two().min(64),
            _ => config.leaf_cells.max(1),
        };
        let tree = StoreTree::new(store.clone(), leaf_cells);
        let shape = *tree.shape();
        let dir = store.dir().to_path_buf();
        if let Some(r) = reference
            && r.qt.shape() != &shape
        {
            return Err(not_the_reference(&dir, "quadtree", &shape, r));
        }
        if let Some(r) = reference {
            check_same_heights(&store, &r.hm)?;
        }
        let tables = match kind {
            LodMethod::Uniform => Tables::None,
            LodMethod::PvpsA | LodMethod::PvpsB | LodMethod::PvpsC => {
                Tables::Roughness(read_roughness(&store, kind, &shape)?)
            }
            LodMethod::PvpsCPvs | LodMethod::PvpsCConservative => {
                let mode = if kind == LodMethod::PvpsCPvs {
                    PvsMode::Sampled
                } else {
                    PvsMode::Conservative
                };
                let path = crate::pvs_scene::pvs_path(&dir, mode);
                // A remote store's PVS comes into its mirror now (only this method reads it).
                store.side_file(crate::pvs_scene::pvs_file(mode))?;
                let pvs = match read_pvs(&path) {
                    Ok(p) if p.mode == mode && p.matches(&shape) => Some(p),
                    Ok(_) => {
                        eprintln!(
                            "warning: {} was baked for another grid or mode; drawing without \
                             occlusion culling",
                            path.display()
                        );
                        None
                    }
                    Err(e) => {
                        eprintln!(
                            "warning: {e}; drawing without occlusion culling (the bake skips \
                             the PVS where it would not pay: bake the store with --pvs to have it)"
                        );
                        None
                    }
                };
                Tables::RoughnessPvs(read_roughness(&store, LodMethod::PvpsC, &shape)?, pvs)
            }
            LodMethod::Geomorph => {
                let budget = scene.config().budget_bytes;
                let table = crate::geomip_scene::read_for_store_within(&store, &shape, budget)?
                    .exaggerated(vertical_scale);
                let lib = MeshLibrary::new(table.patch_cells());
                Tables::Geomip(table, lib)
            }
            _ => {
                // A store baked without the DSS errors (`--no-dss`, `terrain demo`) has neither
                // the per-block errors in its index nor the per-node table beside it.
                // (A remote store's table is not fetched to know: it may be read by pages.)
                if !store.has_dss_errors() && !store.has_side_file(crate::dss_scene::DSS_FILE)? {
                    anyhow::bail!(
                        "--method {} needs the DSS paper's object-space errors, and the store {} \
                         was baked without them (no per-block errors in its index, no {} beside \
                         it: terrain bake --no-dss, or terrain demo's bake): bake it again \
                         without --no-dss, or use ooc or uniform on this store",
                        kind.name(),
                        dir.display(),
                        crate::dss_scene::DSS_FILE
                    );
                }
                let table = crate::dss_scene::read_for_store(
                    &store,
                    &shape,
                    kind.name(),
                    crate::geomip_scene::READ_WHOLE_MAX_BYTES,
                    crate::scene_files::table_cache_bytes(scene.config().budget_bytes),
                )?
                .exaggerated(vertical_scale);
                Tables::Dss(table)
            }
        };
        let scene = runtime_for(scene, wait, reference.is_some());
        Ok(Self {
            kind,
            scene,
            tree,
            tables,
            config: config.clone(),
            reference,
            wait,
            frames: 0,
            vertical_scale,
        })
    }
}

/// The roughness pyramid of PVPS method `kind` from `store`'s folder (`roughness.bin`, tied
/// to the store; [`crate::roughness_scene::load_from_opened`]).
fn read_roughness(
    store: &terrain_stream::Store,
    kind: LodMethod,
    shape: &terrain_core::quadtree::TreeShape,
) -> anyhow::Result<NodePyramid> {
    let tables =
        crate::roughness_scene::load_from_opened(store, shape.leaf_cells()).with_context(|| {
            format!(
                "--method {} from a store reads the roughness pyramids the bake writes for \
             quadtrees of 16-cell leaves (this run asks for {}-cell leaves): bake the store \
             again without --no-roughness, or keep the default --leaf-cells",
                kind.name(),
                shape.leaf_cells()
            )
        })?;
    Ok(match kind {
        LodMethod::PvpsA => tables.a,
        LodMethod::PvpsB => tables.b,
        _ => tables.c,
    })
}

/// The runtime a store method draws through: [`mirrored`] when `measured` against a DEM in
/// memory, and [`OocScene::with_real_time`] when its frames after the first do not wait.
fn runtime_for(scene: OocScene, wait: OocWait, measured: bool) -> OocScene {
    let scene = if measured { mirrored(scene, wait) } else { scene };
    if wait == OocWait::FirstFrame { scene.with_real_time() } else { scene }
}

impl Method for StoreMethod<'_> {
    fn kind(&self) -> LodMethod {
        self.kind
    }

    fn frame(&mut self, camera: &Camera) -> Frame {
        let warm = self.wait.next_is_warm(&mut self.frames);
        let later = self.frames > 1;
        let (cfg, tables) = (&self.config, &self.tables);
        let kind = self.kind;
        let vertical_scale = self.vertical_scale;
        // `drawn`: false for a selection only the store's demand reads (Eq. 8's eye ahead),
        // which builds no strips.
        let select_at = |src: &dyn TerrainSource, camera: &Camera, drawn: bool| -> StoreDraw {
            // The PVS of the unexaggerated terrain, looked up where the eye is over it.
            let mut pvs_eye = camera.position;
            pvs_eye.z /= vertical_scale;
            let selection = match tables {
                Tables::None => select_uniform(src, camera, cfg.uniform_factor),
                Tables::Roughness(field) => select_pvps(src, camera, field, &cfg.pvps),
                Tables::RoughnessPvs(field, Some(pvs)) => {
                    select_pvps_with_cull(src, camera, field, &cfg.pvps, &mut pvs.cull_for(pvs_eye))
                }
                Tables::RoughnessPvs(field, None) => select_pvps(src, camera, field, &cfg.pvps),
                Tables::Dss(table) if kind.has_strips() => {
                    let factors = kind.strip_factors().unwrap_or_default();
                    let f = strips_frame(src, camera, table, cfg, factors, drawn);
                    return StoreDraw {
                        selection: f.selection,
                        strips: f.strips,
                        ..Default::default()
                    };
                }
                Tables::Dss(table) if kind == LodMethod::Dss1 => {
                    select_dss_power_of_two(src, camera, table, &cfg.dss)
                }
                Tables::Dss(table) => select_dss_uniform(src, camera, table, &cfg.dss),
                Tables::Geomip(table, _) => {
                    // The morph's levels and tween factors, compact, as from memory
                    // (`MethodScene::select_geomorph_runs`; the selection's time is the runs',
                    // drawn without expansion). The streamer's demand and the drawn-block
                    // filter work on the runs (`morph_demand`, `morph_on_pages`); the
                    // coverage's patches are built only when the frame is measured
                    // (`surface`).
                    let geomip = GeomipConfig { patch_cells: table.patch_cells(), ..cfg.geomip };
                    // A remote table read by pages: a warm frame waits for the pages it reads,
                    // any other bounds the patches of a page not here yet by the coarse
                    // pyramid (finer, never coarser). From the second frame on the rest of the
                    // table is fetched in the background (one view fetches only its pages).
                    if later {
                        table.fetch_all_in_background();
                    }
                    table.set_waiting(warm);
                    // A page of `geomip.bin` that cannot be read is reported (once per
                    // frame that needs it) and its patches drawn at the finest level.
                    let runs = table.try_select_runs(&src, camera, &geomip).unwrap_or_else(|e| {
                        eprintln!("error: geomorph's table: {e}");
                        table.select_runs(&src, camera, &geomip)
                    });
                    let stats = SelectionStats {
                        culled: runs.culled,
                        max_level: src.shape().max_level(),
                        cpu_time: std::time::Duration::from_secs_f64(runs.cpu_ms / 1e3),
                        ..SelectionStats::default()
                    };
                    let patch_cells = table.patch_cells();
                    return StoreDraw {
                        selection: Selection { patches: Vec::new(), stats },
                        morph: Some(MorphDraw { runs, patch_cells }),
                        ..Default::default()
                    };
                }
            };
            StoreDraw { selection, ..Default::default() }
        };
        let late_pages = || tables.paging().0;
        // The table pages the selection for the eye ahead (Eq. 8) found missing are fetched
        // for the next frames, not late for this one's drawing.
        let (frame_camera, mut ahead_late) = (*camera, 0);
        let mut select = |src: &dyn TerrainSource, c: &Camera| -> StoreDraw {
            if *c == frame_camera {
                return select_at(src, c, true);
            }
            let before = late_pages();
            let draw = select_at(src, c, false);
            ahead_late += late_pages() - before;
            draw
        };
        let late_before = late_pages();
        // A table read by pages keeps its cache within the one memory budget: the blocks get
        // what it holds now less (`OocScene::set_reserved`).
        self.scene.set_reserved(tables.paging().1);
        let mut frame = paged_frame(self.scene.frame_for(camera, warm, &self.tree, &mut select));
        if let Some(s) = frame.stats.stream.as_mut() {
            s.late_table_pages = late_pages() - late_before - ahead_late;
        }
        // A page of `dss_errors.bin` read by pages that cannot be used is reported once; its
        // nodes were split to the finest factor.
        if let Tables::Dss(t) = &self.tables
            && let Some(e) = t.take_error()
        {
            eprintln!("error: the DSS errors' table: {e} (its nodes drawn at the finest factor)");
        }
        frame.draw = match frame.draw {
            Draw::Paged(mut f) => match f.morph.take() {
                // Only the patches over drawn blocks (`frame_for` kept them: a run wholly over
                // drawn blocks stays one).
                Some(lods) => {
                    frame.stats.patches = lods.drawn_patches() as usize;
                    Draw::PagedMorph(f, lods)
                }
                None => Draw::Paged(f),
            },
            other => other,
        };
        frame
    }

    /// The surface drawn from the pages' heights (the paged renderer's CPU reference; for
    /// geomorph the morph's, `MorphGrid` over the pages).
    fn surface(&self, frame: &mut Frame) -> anyhow::Result<DrawnSurface> {
        let (Draw::PagedMorph(_, lods), Tables::Geomip(table, lib)) = (&frame.draw, &self.tables)
        else {
            return paged_surface(&self.scene, self.reference, frame);
        };
        let Some(reference) = self.reference else {
            anyhow::bail!("a method drawn from a store is measured only against a DEM in memory");
        };
        // The coverage the measurement reads, patch by patch, built here only (the frame
        // itself works on the runs): the same `Selection` as of the expansion.
        let n = table.patch_cells();
        if frame.selection.patches.is_empty() {
            let stats = frame.selection.stats;
            frame.selection = geomorph_selection_runs(lods, n, self.tree.shape().max_level());
            frame.selection.stats = SelectionStats {
                traversal_leaves: frame.selection.patches.len(),
                patches: frame.selection.patches.len(),
                ..stats
            };
        }
        // The pages' heights where resident (the mirror's lookup), the DEM's elsewhere (no
        // patch is drawn there); the DEM's when every frame waits (`drawn_heights`).
        let drawn = drawn_heights(&self.scene, reference);
        // The runs expanded here, for the measurement only (row-major, as the selection's own
        // expansion).
        let patches: Vec<GpuMorphPatch> =
            lods.expand().patches.iter().map(|p| GpuMorphPatch::from_lod(p, n)).collect();
        let (mesh, triangles) = build_surface(&MorphGrid::new(drawn.as_ref(), n), lib, &patches);
        Ok(DrawnSurface { mesh, triangles })
    }

    /// Geomorph: the jump from `previous`'s morphed surface, and the same with tweening off,
    /// as from memory (`GeomorphMethod::vertex_jumps`), both cameras selected over the store's
    /// terrain as it is now and drawn from the pages' heights now (a warm frame's are the
    /// exact heights, so the previous frame's surface is the one it drew).
    fn vertex_jumps(
        &self,
        previous: &Camera,
        camera: &Camera,
        drawn: &DrawnSurface,
    ) -> Option<[f64; 2]> {
        let (Tables::Geomip(table, lib), Some(reference)) = (&self.tables, self.reference) else {
            return None;
        };
        let heights = drawn_heights(&self.scene, reference);
        let src = StoreSource::new(&self.tree, self.scene.streamer());
        let n = table.patch_cells();
        let grid = MorphGrid::new(heights.as_ref(), n);
        let surface = |c: &Camera, morph: bool| {
            let cfg = GeomipConfig { patch_cells: n, morph, ..self.config.geomip };
            let lods = table.select(&src, c, &cfg);
            let patches: Vec<GpuMorphPatch> =
                lods.patches.iter().map(|p| GpuMorphPatch::from_lod(p, n)).collect();
            build_surface(&grid, lib, &patches).0
        };
        let morph = max_vertex_jump(&surface(previous, true), &drawn.mesh);
        Some([morph, max_vertex_jump(&surface(previous, false), &surface(camera, false))])
    }

    fn draws_on(&self) -> DrawSource<'_> {
        match &self.tables {
            Tables::Geomip(table, _) => DrawSource::PagedMorph(&self.scene, table.patch_cells()),
            _ => DrawSource::Paged(&self.scene),
        }
    }

    fn hold_io(&mut self, held: bool) {
        self.scene.hold_io(held);
    }
}

#[cfg(test)]
mod tests {
    use super::check_same_heights;
    use terrain_core::{Georef, Heightmap};
    use terrain_stream::{BakeConfig, BakeProgress, Store, bake};

    /// The store-vs-DEM height check accepts the DEM a store was baked from and refuses the
    /// same DEM mirrored north-south (what a raw file written south row first gave: the
    /// benchmark then measured the 32769^2 store against another terrain) or raised by 1 m.
    #[test]
    fn a_store_is_measured_only_against_its_own_heights() {
        let f = |i: usize, j: usize| 100.0 + 3.0 * j as f32 + ((i * 7 + j * 13) % 11) as f32;
        let hm = Heightmap::from_fn(129, 129, Georef::local(10.0), f).unwrap();
        // Removed when dropped, also when the test panics.
        let tmp = tempfile::Builder::new().prefix("terrain-app-same-heights-").tempdir().unwrap();
        let dir = tmp.path().join("store");
        let cfg = BakeConfig { k: 5, node_levels: 3, ..Default::default() };
        bake(&hm, &dir, &cfg, &mut |_: &BakeProgress| std::ops::ControlFlow::Continue(())).unwrap();
        let store = Store::open(&dir).unwrap();
        check_same_heights(&store, &hm).unwrap();
        let mirrored =
            Heightmap::from_fn(129, 129, Georef::local(10.0), |i, j| f(i, 128 - j)).unwrap();
        let err = check_same_heights(&store, &mirrored).unwrap_err().to_string();
        assert!(err.contains("does not hold the heights"), "{err}");
        let raised =
            Heightmap::from_fn(129, 129, Georef::local(10.0), |i, j| f(i, j) + 1.0).unwrap();
        assert!(check_same_heights(&store, &raised).is_err());
    }
}
