//! `terrain pvs`: a view cell's potential visible patch set as a PNG (1 = visible = white),
//! from a scene folder's PVS file or baked from a DEM on the fly; and the PVS part of
//! `terrain bake` (its flags and writing the files into the scene).

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use clap::Args;
use std::time::Instant;
use terrain_app::progress::Progress;
use terrain_app::pvs_scene::pvs_path;

use terrain_core::Heightmap;
use terrain_core::georef::Georef;
use terrain_core::quadtree::NodeId;
use terrain_visibility::pvs::coarse::{BYTES_PER_COARSE_SAMPLE, CoarseTerrain, factor_for};
use terrain_visibility::pvs::{
    CellId, CullEstimate, FloorRule, Pvs, PvsConfig, PvsMode, bake, bake_both_with_progress,
    cells_per_side, estimate_cull, read_pvs, write_pvs,
};

use crate::source::SourceArgs;

/// The PVS bake's settings (shared by `terrain bake` and `terrain pvs`).
#[derive(Debug, Args)]
pub(crate) struct PvsArgs {
    /// View cells per side (default: half the patches per side, the paper's 32 x 32 cells
    /// over 64 x 64 patches; see --pvs-patch-level).
    #[arg(long)]
    pub pvs_cells: Option<u32>,
    /// Floors of view cells (the paper: 3).
    #[arg(long, default_value_t = 3)]
    pub pvs_floors: u32,
    /// Floor height in metres (default: the DEM's relief / floors).
    #[arg(long)]
    pub pvs_floor_height: Option<f64>,
    /// Patch grid level: 2^L x 2^L patches (default: patches of the paper's 64 cells a side,
    /// L = log2(root cells / 64), at most the paper's 6: 64 x 64 patches on a 4096^2 DEM,
    /// 32 x 32 on a 1201^2 one).
    #[arg(long)]
    pub pvs_patch_level: Option<u8>,
    /// Test points per patch side (the paper: 7).
    #[arg(long, default_value_t = 7)]
    pub pvs_test_points: u32,
    /// The geomorphing article's variant: cells on the patch grid, 32 layers up to three
    /// reliefs (not with the cell and floor flags, which it replaces).
    #[arg(long, conflicts_with_all = ["pvs_cells", "pvs_floors", "pvs_floor_height"])]
    pub pvs_article: bool,
    /// PVS bake threads (0 = one per core).
    #[arg(long, default_value_t = 0)]
    pub pvs_threads: usize,
}

impl PvsArgs {
    /// The `--pvs-*` options given (not at their defaults): refused where no PVS is baked.
    pub(crate) fn given(&self) -> Vec<&'static str> {
        [
            ("--pvs-cells", self.pvs_cells.is_some()),
            ("--pvs-floors", self.pvs_floors != 3),
            ("--pvs-floor-height", self.pvs_floor_height.is_some()),
            ("--pvs-patch-level", self.pvs_patch_level.is_some()),
            ("--pvs-test-points", self.pvs_test_points != 7),
            ("--pvs-article", self.pvs_article),
            ("--pvs-threads", self.pvs_threads != 0),
        ]
        .iter()
        .filter(|(_, g)| *g)
        .map(|(name, _)| *name)
        .collect()
    }

    /// The bake configuration for a `width x height` grid: the paper's, scaled to the grid
    /// ([`PvsConfig::scaled`]) where `--pvs-cells` and `--pvs-patch-level` are not given.
    pub(crate) fn config(&self, width: u32, height: u32) -> anyhow::Result<PvsConfig> {
        let scaled = PvsConfig::scaled(width, height);
        let patch_level = self.pvs_patch_level.unwrap_or(scaled.patch_level);
        if patch_level > 10 {
            bail!("--pvs-patch-level must be at most 10");
        }
        let mut cfg = if self.pvs_article {
            PvsConfig::article(patch_level)
        } else {
            // Half the patches per side, from the patch level used (given or scaled).
            let cells = self.pvs_cells.unwrap_or_else(|| cells_per_side(patch_level));
            if cells == 0 || self.pvs_floors == 0 {
                bail!("--pvs-cells and --pvs-floors must be at least 1");
            }
            PvsConfig {
                cells: (cells, cells),
                floors: self.pvs_floors,
                floor_rule: FloorRule::AboveTerrain { height_m: self.pvs_floor_height },
                patch_level,
                ..PvsConfig::default()
            }
        };
        cfg.test_points = self.pvs_test_points.max(1);
        cfg.threads = self.pvs_threads;
        Ok(cfg)
    }
}

/// The least fraction of (view cell, patch) pairs that the paper's sampled PVS must hide in
/// a spread sample of the view cells ([`terrain_visibility::pvs::estimate_cull`]) for
/// `terrain bake` to bake the PVS by default. Measured on seven DEMs (bench/ooc/README.md,
/// "The PVS only where it pays"): along the shipped flights `pvps-c-pvs` drew at most 4 % fewer
/// triangles than `pvps-c` (the conservative PVS at most 1.4 %) where the PVS hid 13-40 % of
/// the pairs, for a bake of 15-300 times the rest of a default bake's CPU time; half the pairs
/// is above every measured terrain.
pub(crate) const PVS_MIN_CULLED: f64 = 0.5;

/// The sample's plan cells per side: the middle cell of each of 4 x 4 blocks of the layout,
/// 16 plan cells with all their floors whatever the grid (1/64 of the paper's 32 x 32).
const PVS_SAMPLE_SIDE: u32 = 4;

/// The stride of a sample of [`PVS_SAMPLE_SIDE`]^2 plan cells of `cfg`'s layout.
fn sample_stride(cfg: &PvsConfig) -> u32 {
    (cfg.cells.0.max(cfg.cells.1) / PVS_SAMPLE_SIDE).max(1)
}

/// When `terrain bake` bakes the PVS.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum When {
    /// Whatever it culls (`--pvs`, or a `--pvs-*` option).
    Always,
    /// Only when a spread sample of its view cells hides at least [`PVS_MIN_CULLED`] of the
    /// patches (the default).
    IfItPays,
}

/// Whether the PVS is worth baking by `when` and the sample's estimate (printed either way).
fn pays(when: When, estimate: impl FnOnce() -> CullEstimate) -> bool {
    if when == When::Always {
        return true;
    }
    let e = estimate();
    let pays = e.sampled >= PVS_MIN_CULLED;
    println!(
        "PVS sample: {} of {} view cell columns in {:.1} s hide {:.1} % of the patches \
         (conservative {:.1} %): {}",
        e.plan_cells,
        e.plan_total,
        e.elapsed.as_secs_f64(),
        100.0 * e.sampled,
        100.0 * e.conservative,
        if pays {
            "baking the PVS".to_string()
        } else {
            format!(
                "under {:.0} %, so no PVS is baked (it would not pay; --pvs bakes it anyway)",
                100.0 * PVS_MIN_CULLED
            )
        }
    );
    pays
}

/// Bakes both PVS modes of `hm` and writes them into scene folder `dir` (by `when`: always,
/// or only where a sample says it pays).
pub(crate) fn bake_into_scene(
    hm: &Heightmap,
    cfg: &PvsConfig,
    dir: &Path,
    when: When,
) -> anyhow::Result<()> {
    if !pays(when, || estimate_cull(hm, cfg, sample_stride(cfg))) {
        return Ok(());
    }
    let bar = Progress::new("PVS", true);
    let (sampled, conservative, stats) =
        bake_both_with_progress(hm, cfg, &|done, total| bar.update(done as f64, total as f64));
    bar.finish();
    write_into_scene(&[&sampled, &conservative], stats.cells, dir)?;
    println!("PVS bake: {:.1} s", stats.elapsed.as_secs_f64());
    Ok(())
}

/// Bakes both PVS modes of a `width x height` grid at `georef` that is not held in memory (by
/// `when`, the sample taken on the coarse terrain),
/// reading it through `read(j0, rows, heights, voids)` by bands of rows, against a coarse
/// conservative version of it that fits `max_bytes` (terrain-visibility's `pvs::coarse`:
/// occluders never above, targets never below the terrain), and writes them into scene folder
/// `dir`. The files keep the grid's layout and the CRC-32 of its full-resolution heights.
pub(crate) fn bake_by_rows_into_scene(
    (width, height, georef): (usize, usize, &Georef),
    cfg: &PvsConfig,
    max_bytes: u64,
    dir: &Path,
    when: When,
    read: impl Fn(usize, usize, &mut [f32], &mut [bool]) -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    let start = Instant::now();
    let (factor, fits) = factor_for(width as u64, height as u64, cfg, max_bytes);
    let coarse_side = |n: usize| (n.saturating_sub(1)).div_ceil(factor as usize) + 1;
    let coarse_mib = (coarse_side(width) * coarse_side(height)) as f64
        * BYTES_PER_COARSE_SAMPLE as f64
        / terrain_app::MIB;
    if !fits {
        eprintln!(
            "warning: the PVS bake's coarse grid needs {coarse_mib:.0} MiB, more than its budget \
             of {:.0} MiB (a quarter of --max-memory): it is coarsened at most to one coarse \
             cell per patch (factor {factor}); a smaller --pvs-patch-level coarsens further",
            max_bytes as f64 / terrain_app::MIB
        );
    }
    // A band of rows in at most an eighth of the budget (5 bytes a sample: height and void).
    let band = ((max_bytes / 8) / (5 * width.max(1) as u64)).clamp(1, 4096) as usize;
    let coarse =
        CoarseTerrain::from_rows(width, height, georef, cfg, factor, band, |j0, n, h, v| {
            read(j0, n, h, v)
        })
        .context("reading the grid by rows for the PVS")?;
    let gathered = start.elapsed();
    if !pays(when, || coarse.estimate_cull(cfg, sample_stride(cfg))) {
        return Ok(());
    }
    let (cw, ch) = (coarse.occluders.width(), coarse.occluders.height());
    let bar = Progress::new("PVS", true);
    let (sampled, conservative, stats) =
        coarse.bake_both(cfg, &|done, total| bar.update(done as f64, total as f64));
    bar.finish();
    write_into_scene(&[&sampled, &conservative], stats.cells, dir)?;
    println!(
        "PVS bake: {:.1} s (by bands of rows: against a {cw} x {ch} conservative grid, {factor}x \
         coarser, about {coarse_mib:.0} MiB; rows read in {:.1} s)",
        start.elapsed().as_secs_f64(),
        gathered.as_secs_f64()
    );
    Ok(())
}

/// Writes baked PVSs into scene folder `dir`, with one line each.
fn write_into_scene(pvss: &[&Pvs], cells: usize, dir: &Path) -> anyhow::Result<()> {
    for pvs in pvss {
        let path = pvs_path(dir, pvs.mode);
        let bytes = write_pvs(pvs, &path).with_context(|| format!("writing {}", path.display()))?;
        println!(
            "{}: {} PVS of {} cells x {}^2 patches, {:.1} KB, culled {:.1} % of (cell, patch) pairs, {:.1} visible patches per cell",
            path.display(),
            pvs.mode.name(),
            cells,
            pvs.layout.patches_per_side(),
            bytes as f64 / 1e3,
            100.0 * pvs.culled_fraction(),
            visible_per_cell(pvs)
        );
    }
    Ok(())
}

/// The mean number of finest patches holding samples that a PVS keeps per view cell inside
/// the grid.
pub(crate) fn visible_per_cell(pvs: &Pvs) -> f64 {
    let lay = &pvs.layout;
    let (l, side) = (lay.patch_level, lay.patches_per_side());
    let (mut visible, mut cells) = (0u64, 0u64);
    for n in 0..lay.cell_count() {
        let c = lay.cell_at_index(n);
        if lay.floor_bounds(c).is_none() {
            continue;
        }
        cells += 1;
        for b in 0..side {
            for a in 0..side {
                if lay.patch_samples(l, a, b).is_some() {
                    visible += u64::from(pvs.visible(c, NodeId::new(l, a, b)));
                }
            }
        }
    }
    visible as f64 / cells.max(1) as f64
}

/// Arguments of `terrain pvs`.
#[derive(Debug, Args)]
pub(crate) struct PvsCmdArgs {
    /// The positional argument is a scene folder from `terrain bake` (its PVS file is read)
    /// or a DEM file (the PVS is baked in memory with the `--pvs-*` settings).
    #[command(flatten)]
    pub source: SourceArgs,
    /// The view cell: column, row, floor (e.g. `12,7,0`).
    #[arg(long)]
    pub cell: String,
    /// Output PNG (north up; white = visible).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Use the conservative PVS instead of the paper's sampled one.
    #[arg(long)]
    pub conservative: bool,
    /// Pyramid level to export (default: the patch level, the finest).
    #[arg(long)]
    pub level: Option<u8>,
    /// Pixels per patch in the PNG.
    #[arg(long, default_value_t = 4)]
    pub scale: u32,
    #[command(flatten)]
    pub pvs: PvsArgs,
}

/// Parses `i,j,k`.
fn parse_cell(s: &str) -> anyhow::Result<CellId> {
    let v: Vec<u32> = s
        .split(',')
        .map(|p| p.trim().parse::<u32>())
        .collect::<Result<_, _>>()
        .with_context(|| format!("--cell {s}: expected three integers i,j,k"))?;
    match v[..] {
        [a, b, k] => Ok(CellId { a, b, k }),
        _ => bail!("--cell {s}: expected three integers i,j,k"),
    }
}

/// Runs `terrain pvs`.
pub(crate) fn run(args: &PvsCmdArgs) -> anyhow::Result<()> {
    let cell = parse_cell(&args.cell)?;
    let mode = if args.conservative { PvsMode::Conservative } else { PvsMode::Sampled };
    let Some(scene) = args.source.dem.first() else {
        bail!("give a scene folder (from terrain bake) or a DEM file");
    };
    let pvs: Pvs = if scene.is_dir() {
        args.source.refuse_reading_options("a scene folder (its PVS is baked)")?;
        if let Some(first) = args.pvs.given().first() {
            bail!("{first} applies to a PVS baked from a DEM file; a scene folder's is baked");
        }
        let path = pvs_path(scene, mode);
        read_pvs(&path).with_context(|| format!("reading the PVS of scene {}", scene.display()))?
    } else {
        let dem = args.source.load()?.context("give a scene folder or a DEM file")?;
        let hm = &dem.heightmap;
        let cfg = PvsConfig { mode, ..args.pvs.config(hm.width() as u32, hm.height() as u32)? };
        bake(&dem.heightmap, &cfg)
    };
    let lay = &pvs.layout;
    if cell.a >= lay.cells_x || cell.b >= lay.cells_y || cell.k >= lay.floors {
        bail!(
            "--cell {}: out of range, the PVS has {} x {} cells x {} floors",
            args.cell,
            lay.cells_x,
            lay.cells_y,
            lay.floors
        );
    }
    let level = args.level.unwrap_or(lay.patch_level);
    if level > lay.patch_level {
        bail!("--level {level}: the PVS pyramid has levels 0..={}", lay.patch_level);
    }
    let side = 1u32 << level;
    let bits = pvs.level_image(cell, level);
    let s = args.scale.clamp(1, 64);
    let img = image::GrayImage::from_fn(side * s, side * s, |x, y| {
        // Rows of the image run north to south; the bits are south row first.
        let (i, j) = (x / s, side - 1 - y / s);
        image::Luma([if bits[(j * side + i) as usize] == 1 { 255 } else { 0 }])
    });
    img.save(&args.output).with_context(|| format!("writing {}", args.output.display()))?;
    let visible = bits.iter().filter(|&&b| b == 1).count();
    println!(
        "{}: cell {},{},{} ({}), level {level}: {visible} of {} patches visible",
        args.output.display(),
        cell.a,
        cell.b,
        cell.k,
        pvs.mode.name(),
        bits.len()
    );
    Ok(())
}
