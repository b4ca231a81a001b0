//! `tin`: our own LOD method, an error-bounded TIN pyramid on the grid's quadtree
//! ([`terrain_core::tin::grid`]): per frame, tiles chosen by Cesium's screen-space error
//! against `tau_px` and frustum-culled, joined by stitches where levels meet, drawn as the
//! tessellation renderer's extra triangles on one carrier patch ([`entropy_extra`], as the
//! entropy mesh) and measured on the CPU as built. The pyramid is built once per terrain
//! ([`build_pyramid`]: every tile on rayon's threads, with a progress line on a terminal).

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use rayon::prelude::*;
use terrain_core::Heightmap;
use terrain_core::geometry::Camera;
use terrain_core::lod::{Patch, Selection, SelectionStats};
use terrain_core::tin::TinError;
use terrain_core::tin::grid::{GridTinConfig, GridTinPyramid, TinSelection};

use super::memory::ms;
use super::{Draw, DrawSource, DrawnSurface, Frame, Method, MethodStats, entropy_extra};
use crate::methods::{LodMethod, MethodScene};
use crate::progress::{Progress, on_terminal};

/// The `tin` method's settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TinConfig {
    /// Cesium's screen-space error threshold, pixels: a tile is refined while
    /// `e_L lambda / d > tau_px`. Default 1.
    pub tau_px: f64,
    /// The pyramid (bounds per level, finest tiles).
    pub pyramid: GridTinConfig,
    /// Close the gaps where a tile meets finer ones with stitches (default true; false is the
    /// crack test's negative control).
    pub stitch: bool,
    /// How a store is read ([`super::TinStoreMethod`]).
    pub store: super::TinStoreConfig,
}

impl Default for TinConfig {
    fn default() -> Self {
        Self {
            tau_px: 1.0,
            pyramid: GridTinConfig::default(),
            stitch: true,
            store: super::TinStoreConfig::default(),
        }
    }
}

/// Builds the pyramid of `hm` on rayon's threads (tiles weighted by their samples in the
/// progress line, shown on a terminal only).
pub fn build_pyramid(hm: &Heightmap, config: &GridTinConfig) -> Result<GridTinPyramid, TinError> {
    let bar = Progress::new("TIN pyramid", on_terminal());
    let total = (hm.width() * hm.height()) as f64;
    let done = AtomicU64::new(0);
    let pyramid = GridTinPyramid::build_with(hm, config, |nodes, build| {
        let levels = nodes.iter().map(|n| n.level).max().map_or(1, |l| u64::from(l) + 1);
        nodes
            .par_iter()
            .map(|&n| {
                let t = build(n);
                if let Ok(t) = &t {
                    let samples = t.measured.samples.max(1) as u64;
                    let now = done.fetch_add(samples, Ordering::Relaxed) + samples;
                    bar.update(now as f64, total * levels as f64);
                }
                t
            })
            .collect()
    })?;
    bar.finish();
    Ok(pyramid)
}

/// The tiles of a frame as a [`Selection`] of their nodes (what the measurement counts as
/// covered; the factors are not used).
pub fn tin_selection(sel: &TinSelection) -> Selection {
    let patches: Vec<Patch> =
        sel.tiles.iter().map(|&node| Patch { node, outer: [1.0; 4], inner: [1.0; 2] }).collect();
    let stats = SelectionStats {
        traversal_leaves: patches.len(),
        patches: patches.len(),
        culled: sel.culled,
        max_level: patches.iter().map(|p| p.node.level).max().unwrap_or(0),
        cpu_time: sel.cpu_time,
        ..SelectionStats::default()
    };
    Selection { patches, stats }
}

/// `tin` over a [`MethodScene`] (its pyramid and current config).
#[derive(Debug)]
pub struct TinMethod<'a> {
    scene: &'a MethodScene,
    pyramid: &'a GridTinPyramid,
}

impl<'a> TinMethod<'a> {
    /// The method over `scene`, its pyramid built on first use.
    pub fn new(scene: &'a MethodScene) -> anyhow::Result<Self> {
        Ok(Self { scene, pyramid: scene.tin_pyramid()? })
    }
}

impl Method for TinMethod<'_> {
    fn kind(&self) -> LodMethod {
        LodMethod::Tin
    }

    /// The traversal is the selection time; joining the tiles' meshes and the stitches the
    /// build time (the benchmark's tessellation time).
    fn frame(&mut self, camera: &Camera) -> Frame {
        let (scene, config) = (self.scene, &self.scene.config.tin);
        let sel = self.pyramid.select(camera, config.tau_px);
        let t = Instant::now();
        let surface = self.pyramid.surface(&scene.hm, &sel.tiles, config.stitch);
        let build_ms = ms(t);
        let t = Instant::now();
        let (carrier, extra) = entropy_extra(&scene.hm, &surface.mesh);
        let convert_ms = ms(t);
        let triangles = surface.tile_triangles + surface.stitch_triangles;
        Frame {
            selection: tin_selection(&sel),
            draw: Draw::Tessellated { patches: vec![carrier], extra },
            stats: MethodStats {
                selection_ms: sel.cpu_time.as_secs_f64() * 1e3,
                build_ms,
                convert_ms,
                patches: sel.tiles.len(),
                ..MethodStats::default()
            },
            built: Some((surface.mesh, triangles)),
        }
    }

    fn surface(&self, frame: &mut Frame) -> anyhow::Result<DrawnSurface> {
        let (mesh, triangles) = frame
            .built
            .take()
            .ok_or_else(|| anyhow::anyhow!("the tin frame's mesh was already taken"))?;
        Ok(DrawnSurface { mesh, triangles })
    }

    fn draws_on(&self) -> DrawSource<'_> {
        DrawSource::Tessellation(&self.scene.hm)
    }
}
