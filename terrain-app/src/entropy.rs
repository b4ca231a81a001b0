//! `terrain entropy`: the entropy paper's (Chen 2018) local curvature entropy map (Eq. 1-3) as
//! a PNG, optionally the profile curvature map beside it, and the curvature-against-entropy
//! comparison of its Fig. 3 and 18 (`--compare`). Also the entropy mesh behind
//! `terrain mesh --entropy` (Algorithm 1, crack elimination, per-tile Delaunay).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use clap::{Args, ValueEnum};
use glam::DVec2;
use terrain_core::Heightmap;
use terrain_core::mesh::TriMesh;
use terrain_core::points::read_points;
use terrain_visibility::entropy::compare::compare_curvature_entropy;
use terrain_visibility::entropy::export::to_grey8;
use terrain_visibility::entropy::local::{class_range, local_entropy_with_range};
use terrain_visibility::entropy::source::build_from_grid_with_map;
use terrain_visibility::entropy::source::entropy_map;
use terrain_visibility::entropy::{
    EntropyConfig, EntropyQuadtree, EntropyScale, FocusThreshold, Interpolation, ScatteredPoints,
    TreeConfig, build_from_points, profile_curvature,
};

use crate::source::SourceArgs;

/// Arguments of `terrain entropy`.
#[derive(Debug, Args)]
pub(crate) struct EntropyArgs {
    #[command(flatten)]
    pub source: SourceArgs,
    /// Output PNG of the local entropy (8-bit grey, north up, 0 .. log2(min(M, N)) bits
    /// mapped to 1..255; voids black). Required unless --table is given.
    #[arg(short, long, required_unless_present = "table")]
    pub output: Option<PathBuf>,
    /// Also write the profile curvature map (8-bit grey, the class range [-c, c] mapped to
    /// 1..255, clipped; voids black).
    #[arg(long)]
    pub curvature: Option<PathBuf>,
    #[command(flatten)]
    pub window: WindowArgs,
    /// Print the curvature-against-entropy comparison (histograms, smoothness, sensitivity to
    /// 0.5 m of height noise) as JSON.
    #[arg(long)]
    pub compare: bool,
    /// Print the entropy paper's Table 1 columns as JSON for these thresholds E0 (percent of
    /// the largest entropy, comma-separated): tiles, triangles, quadtree construction
    /// (Algorithm 1 over the entropy map, computed once and timed apart) and crack-elimination
    /// times, simplification against the full tree of --depth.
    #[arg(long, value_delimiter = ',')]
    pub table: Option<Vec<f64>>,
    /// The quadtree's depth D for --table (the paper's Table 1: 8).
    #[arg(long, default_value_t = 8)]
    pub depth: u32,
    /// With --table: also the static scheduling with four focuses of the paper's Fig. 13 on
    /// each row's tree (focuses at the centres of the grid's quadrants; E = E0 + c1 r with `r`
    /// the distance to the nearest focus and c1 = --focus-c1): tiles and triangles of the cut,
    /// and whether the leaves holding each focus are the tree's own.
    #[arg(long, requires = "table")]
    pub foci: bool,
    /// c1 of --foci, percent of the largest entropy per terrain diagonal (the paper gives none;
    /// 400 raises the threshold by the whole entropy range a quarter diagonal from a focus).
    #[arg(long, default_value_t = 400.0, requires = "foci")]
    pub focus_c1: f64,
}

/// Window and binning of the local entropy (shared with `terrain mesh --entropy`).
#[derive(Debug, Args, Clone)]
pub(crate) struct WindowArgs {
    /// Window radius r: the window is (2r+1)² samples (N of Eq. 2).
    #[arg(long, default_value_t = EntropyConfig::default().radius)]
    pub radius: usize,
    /// Curvature classes M (Eq. 3).
    #[arg(long, default_value_t = EntropyConfig::default().classes)]
    pub classes: usize,
    /// Percentile of |curvature| that bounds the classes (0..1).
    #[arg(long, default_value_t = EntropyConfig::default().clip_percentile)]
    pub clip_percentile: f64,
}

impl WindowArgs {
    /// The entropy configuration, validated.
    pub(crate) fn config(&self) -> anyhow::Result<EntropyConfig> {
        anyhow::ensure!(
            (1..=64).contains(&self.radius),
            "--radius must be 1..=64, got {}",
            self.radius
        );
        anyhow::ensure!(
            (2..=4096).contains(&self.classes),
            "--classes must be 2..=4096, got {}",
            self.classes
        );
        anyhow::ensure!(
            (0.0..=1.0).contains(&self.clip_percentile),
            "--clip-percentile must be within 0..=1, got {}",
            self.clip_percentile
        );
        Ok(EntropyConfig {
            radius: self.radius,
            classes: self.classes,
            clip_percentile: self.clip_percentile,
        })
    }
}

fn write_png(path: &Path, w: usize, h: usize, grey: Vec<u8>) -> anyhow::Result<()> {
    let img = image::GrayImage::from_raw(w as u32, h as u32, grey).context("image size")?;
    img.save(path).with_context(|| format!("could not write {}", path.display()))
}

/// Runs `terrain entropy`.
pub(crate) fn run(args: &EntropyArgs) -> anyhow::Result<()> {
    let cfg = args.window.config()?;
    let hm = match args.source.load()? {
        Some(dem) => dem.heightmap,
        None => terrain_core::synth::default_terrain(),
    };
    if let Some(e0s) = &args.table {
        println!(
            "{}",
            serde_json::to_string_pretty(&table(
                &hm,
                &cfg,
                args.depth,
                e0s,
                args.foci.then_some(args.focus_c1)
            )?)?
        );
        if args.output.is_none() {
            return Ok(());
        }
    }
    let output = args.output.as_ref().context("--output is required without --table")?;
    let t = Instant::now();
    let curv = profile_curvature(&hm);
    let c = class_range(&curv, &cfg);
    let ent = local_entropy_with_range(&curv, &cfg, c);
    let ms = t.elapsed().as_secs_f64() * 1e3;
    let (w, h) = (hm.width(), hm.height());
    write_png(output, w, h, to_grey8(&ent, 0.0, cfg.max_entropy_bits() as f32))?;
    if let Some(p) = &args.curvature {
        write_png(p, w, h, to_grey8(&curv, -c, c))?;
    }
    let (lo, hi) = ent.range().unwrap_or((0.0, 0.0));
    eprintln!(
        "entropy of profile curvature (Zevenbergen-Thorne), {w} x {h}, window {0}x{0}, {1} classes \
         over ±{c:.4}: {lo:.3}..{hi:.3} bits (max possible {2:.3}) in {ms:.0} ms; wrote {3}",
        2 * cfg.radius + 1,
        cfg.classes,
        cfg.max_entropy_bits(),
        output.display()
    );
    if args.compare {
        let r = compare_curvature_entropy(&hm, &cfg, 20, 0.5);
        let json = |s: &terrain_visibility::entropy::compare::MapStats| {
            serde_json::json!({
                "histogram_0_100": s.histogram,
                "fullest_bin_share": s.peak_share,
                "std_dev": s.std_dev,
                "mean_neighbour_diff": s.mean_neighbour_diff,
                "neighbour_diff_over_std": s.relative_neighbour_diff(),
                "noise_change": s.sensitivity,
                "noise_change_over_std": s.relative_sensitivity(),
            })
        };
        let out = serde_json::json!({
            "scale": "both maps min-max scaled to [0, 100] (the paper's Fig. 3), noise ±0.5 m",
            "curvature": json(&r.curvature),
            "entropy": json(&r.entropy),
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
    }
    Ok(())
}

/// `terrain entropy --table`: the entropy paper's Table 1 columns (Chen 2018) for each `E0` of
/// `e0s` at depth `depth`: the entropy map once (timed), then per threshold Algorithm 1 over
/// it (the quadtree construction), the three-pass crack elimination and the per-tile
/// triangulation, each timed on the wall clock, and the simplification against the full
/// tree's `2 x 4^D` triangles (the paper's E0 = 0 row). With `focus_c1`, each row also gets
/// the Fig. 13 cut with four focuses ([`focus_cut`]).
fn table(
    hm: &Heightmap,
    entropy: &EntropyConfig,
    depth: u32,
    e0s: &[f64],
    focus_c1: Option<f64>,
) -> anyhow::Result<serde_json::Value> {
    anyhow::ensure!(
        focus_c1.is_none_or(|c| c.is_finite() && c >= 0.0),
        "--focus-c1 must be a number >= 0"
    );
    anyhow::ensure!(depth <= terrain_visibility::entropy::MAX_DEPTH, "--depth must be 0..=16");
    anyhow::ensure!(e0s.iter().all(|e| e.is_finite()), "--table thresholds must be numbers");
    let base = TreeConfig { max_depth: depth, entropy: entropy.clone(), ..TreeConfig::default() };
    let t = Instant::now();
    let emap = entropy_map(hm, &base);
    let map_s = t.elapsed().as_secs_f64();
    let full = 2u64 << (2 * depth);
    let mut rows = Vec::new();
    for &e0 in e0s {
        let cfg = TreeConfig { e0, ..base.clone() };
        let t = Instant::now();
        let mut tree = build_from_grid_with_map(hm, &emap, &cfg);
        let construction_s = t.elapsed().as_secs_f64();
        let crack_ms = tree.eliminate_cracks() * 1e3;
        let t = Instant::now();
        let mesh = tree.mesh();
        let triangulation_ms = t.elapsed().as_secs_f64() * 1e3;
        mesh.check_watertight(tree.lattice.depth).map_err(|e| {
            anyhow::anyhow!("internal error, the entropy mesh is not watertight: {e}")
        })?;
        let triangles = mesh.triangles.len() as u64;
        let mut row = serde_json::json!({
            "e0": e0,
            "tiles": tree.tiles(),
            "triangles": triangles,
            "construction_s": construction_s,
            "crack_ms": crack_ms,
            "triangulation_ms": triangulation_ms,
            "simplification_pct": 100.0 * (1.0 - triangles as f64 / full as f64),
        });
        if let Some(c1) = focus_c1 {
            row["foci"] = focus_cut(hm, &tree, e0, c1)?;
        }
        rows.push(row);
    }
    Ok(serde_json::json!({
        "width": hm.width(),
        "height": hm.height(),
        "depth": depth,
        "full_triangles": full,
        "entropy_map_s": map_s,
        "e0_unit": "percent of the largest entropy, log2(min(M, N)) bits",
        "rows": rows,
    }))
}

/// The entropy paper's Fig. 13 on `tree` (built at threshold `e0`): the static cut with four
/// focuses at the centres of the grid's quadrants, `E = E0 + c1 r` ([`FocusThreshold`];
/// `c1_pct` in percent per terrain diagonal), made crack-free and triangulated; its tiles and
/// triangles, and whether every focus lies in the same leaves as in the tree (the paper: "the
/// grid cells in the four focus areas maintained the highest resolution").
fn focus_cut(
    hm: &Heightmap,
    tree: &EntropyQuadtree,
    e0: f64,
    c1_pct: f64,
) -> anyhow::Result<serde_json::Value> {
    let (w, h) = (hm.width() as f64 - 1.0, hm.height() as f64 - 1.0);
    let foci: Vec<DVec2> = [(0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75)]
        .iter()
        .map(|&(u, v)| hm.grid_to_world(u * w, v * h))
        .collect();
    let diagonal = hm.extent_m().length().max(1.0);
    let focus = FocusThreshold { e0, c1: c1_pct / diagonal, foci: foci.clone() };
    let t = Instant::now();
    let mut cut = tree.schedule_by(|lo, hi| focus.threshold_tile(lo, hi));
    let cut_ms = t.elapsed().as_secs_f64() * 1e3;
    let mesh = cut.mesh();
    mesh.check_watertight(cut.lattice.depth)
        .map_err(|e| anyhow::anyhow!("internal error, the focus cut is not watertight: {e}"))?;
    let kept = foci.iter().all(|f| cut.leaves_at(*f) == tree.leaves_at(*f));
    Ok(serde_json::json!({
        "focuses": foci.iter().map(|f| [f.x, f.y]).collect::<Vec<_>>(),
        "c1_pct_per_diagonal": c1_pct,
        "tiles": cut.tiles(),
        "triangles": mesh.triangles.len(),
        "cut_ms": cut_ms,
        "focus_leaves_kept": kept,
    }))
}

/// `--interpolation` values.
#[derive(Debug, Clone, Copy, ValueEnum)]
pub(crate) enum InterpolationArg {
    /// Natural-neighbour (Sibson) over the Delaunay triangulation of the points.
    Natural,
    /// Inverse distance weighting, 12 nearest, power 2 (the paper's).
    Idw,
}

/// What `terrain mesh --entropy` built.
pub(crate) struct EntropyMeshResult {
    /// The grid the mesh is measured against (the DEM, or the scattered points' raster).
    pub hm: Heightmap,
    /// The mesh.
    pub mesh: TriMesh,
    /// Tiles (leaves).
    pub tiles: usize,
    /// Algorithm 1 and heights, ms.
    pub build_ms: f64,
    /// The three-pass update, ms.
    pub crack_ms: f64,
    /// Triangles of the full tree at this depth (2 per finest tile), for the simplification.
    pub full_triangles: usize,
}

/// Builds the entropy mesh of `terrain mesh --entropy E0`: from the DEM, or from `points`.
pub(crate) fn build_mesh(
    source: &SourceArgs,
    points: Option<&Path>,
    window: &WindowArgs,
    e0: f64,
    depth: u32,
    interpolation: InterpolationArg,
) -> anyhow::Result<EntropyMeshResult> {
    let cfg = TreeConfig {
        e0,
        max_depth: depth,
        entropy: window.config()?,
        scale: EntropyScale::Percent,
        interpolation: match interpolation {
            InterpolationArg::Natural => Interpolation::NaturalNeighbour,
            InterpolationArg::Idw => Interpolation::IDW,
        },
    };
    let t = Instant::now();
    let (hm, mut tree) = match points {
        Some(path) => {
            // Points have no vertical unit of their own: --vertical-scale and --vertical-offset
            // apply to their z as to a grid's heights (exaggeration or unit conversion).
            source.load_options()?; // checks the scale
            let (scale, offset) = (source.vertical_scale, source.vertical_offset);
            let mut pts = read_points(path)?;
            for p in &mut pts {
                p.z = p.z * scale + offset;
            }
            let src = ScatteredPoints::new(pts, cfg.interpolation)
                .with_context(|| format!("{}", path.display()))?;
            let built = build_from_points(&src, &cfg)?;
            (built.raster, built.tree)
        }
        None => {
            let hm = match source.load()? {
                Some(dem) => dem.heightmap,
                None => terrain_core::synth::default_terrain(),
            };
            anyhow::ensure!(
                depth <= terrain_visibility::entropy::MAX_DEPTH,
                "--depth must be 0..=16"
            );
            anyhow::ensure!(!e0.is_nan(), "--entropy must be a number");
            let emap = entropy_map(&hm, &cfg);
            let tree = build_from_grid_with_map(&hm, &emap, &cfg);
            (hm, tree)
        }
    };
    let build_ms = t.elapsed().as_secs_f64() * 1e3;
    let crack_ms = tree.eliminate_cracks() * 1e3;
    let mesh = tree.mesh();
    mesh.check_watertight(tree.lattice.depth)
        .map_err(|e| anyhow::anyhow!("internal error, the entropy mesh is not watertight: {e}"))?;
    let full_triangles = 2usize << (2 * tree.lattice.depth);
    Ok(EntropyMeshResult {
        hm,
        mesh: mesh.to_trimesh(),
        tiles: tree.tiles(),
        build_ms,
        crack_ms,
        full_triangles,
    })
}
