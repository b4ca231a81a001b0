//! `terrain info`: what a DEM is, in the numbers a user checks first.

use clap::Args;
use serde::Serialize;
use terrain_core::georef::AngularOrLinear;
use terrain_core::{Georef, Heightmap};

use crate::source::SourceArgs;

/// Arguments of `terrain info`.
#[derive(Debug, Args)]
pub(crate) struct InfoArgs {
    #[command(flatten)]
    pub source: SourceArgs,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

/// Everything `terrain info` reports, serialisable for `--json`.
#[derive(Debug, Serialize)]
pub(crate) struct InfoReport {
    pub source: String,
    pub format: String,
    pub sample_type: String,
    pub width: usize,
    pub height: usize,
    pub crs: String,
    pub epsg: Option<u32>,
    pub units: String,
    /// CRS coordinates of the south-west sample's centre.
    pub origin: [f64; 2],
    /// CRS coordinates of the north-east sample's centre.
    pub corner_ne: [f64; 2],
    pub spacing_native: [f64; 2],
    pub spacing_m: [f64; 2],
    pub extent_m: [f64; 2],
    pub min_m: f32,
    pub max_m: f32,
    pub voids: usize,
    pub nodata: Option<f64>,
}

impl InfoReport {
    /// Builds the report for a heightmap and a description of its source.
    pub(crate) fn new(
        hm: &Heightmap,
        source: String,
        format: String,
        sample_type: String,
        nodata: Option<f64>,
    ) -> Self {
        let g: &Georef = hm.georef();
        let ne = g.grid_to_native(glam::dvec2((hm.width() - 1) as f64, (hm.height() - 1) as f64));
        let extent = hm.extent_m();
        Self {
            source,
            format,
            sample_type,
            width: hm.width(),
            height: hm.height(),
            crs: g.crs.to_string(),
            epsg: match g.crs {
                terrain_core::Crs::Epsg(c) => Some(c),
                _ => None,
            },
            units: match (g.units, g.linear_unit_m()) {
                (AngularOrLinear::Degrees, _) => "degrees".into(),
                (AngularOrLinear::Metres, Some(u)) if u != 1.0 => format!("units of {u} m"),
                (AngularOrLinear::Metres, _) => "metres".into(),
            },
            origin: g.native_origin.to_array(),
            corner_ne: ne.to_array(),
            spacing_native: g.native_spacing.to_array(),
            spacing_m: g.spacing_m.to_array(),
            extent_m: extent.to_array(),
            min_m: hm.min(),
            max_m: hm.max(),
            voids: hm.voids().count(),
            nodata,
        }
    }

    /// Human-readable text, one fact per line.
    pub(crate) fn to_text(&self) -> String {
        let n = self.width * self.height;
        let pct = 100.0 * self.voids as f64 / n as f64;
        let unit = match self.units.as_str() {
            "degrees" => "°",
            "metres" => " m",
            _ => " (CRS units)",
        };
        let mut s = String::new();
        s += &format!("source       {}\n", self.source);
        s += &format!("format       {} ({})\n", self.format, self.sample_type);
        s += &format!("size         {} x {} samples ({} samples)\n", self.width, self.height, n);
        s += &format!("crs          {} ({})\n", self.crs, self.units);
        s += &format!(
            "origin (SW)  {:.9}, {:.9}{unit}   (centre of the south-west sample)\n",
            self.origin[0], self.origin[1]
        );
        s += &format!("corner (NE)  {:.9}, {:.9}{unit}\n", self.corner_ne[0], self.corner_ne[1]);
        s += &format!(
            "spacing      {:.9} x {:.9}{unit}\n",
            self.spacing_native[0], self.spacing_native[1]
        );
        s += &format!("spacing (m)  {:.3} x {:.3} m\n", self.spacing_m[0], self.spacing_m[1]);
        s += &format!("extent (m)   {:.1} x {:.1} m\n", self.extent_m[0], self.extent_m[1]);
        s += &format!(
            "heights      {:.2} .. {:.2} m (relief {:.2} m)\n",
            self.min_m,
            self.max_m,
            self.max_m - self.min_m
        );
        let nodata = self
            .nodata
            .map(|v| {
                if v.abs() >= 1e7 { format!(", nodata = {v:e}") } else { format!(", nodata = {v}") }
            })
            .unwrap_or_default();
        s += &format!("voids        {} ({pct:.2}%{nodata}), filled for geometry\n", self.voids);
        s
    }
}

/// What `terrain info` says about a baked store (a folder, not a DEM file).
#[derive(Debug, Serialize)]
pub(crate) struct StoreReport {
    pub store: String,
    pub width: u64,
    pub height: u64,
    pub crs: String,
    pub spacing_m: [f64; 2],
    pub block_side: u32,
    pub blocks: [u32; 2],
    pub encoding: String,
    pub max_error_m: f64,
    pub min_m: f32,
    pub max_m: f32,
    pub bytes: u64,
    /// The per-node tables the store-backed methods read, present in the folder.
    pub tables: Vec<String>,
    /// Whether the index holds the DSS paper's per-block errors (a bake with `--no-dss`, or
    /// `terrain demo`'s, skips them; `dss-1`, `dss-2` and `dss-strips` then refuse the store).
    pub dss_block_errors: bool,
    /// Whether the index holds the fine maxima (index version 3: per deepest stored node, its
    /// descendants' largest `StaticE` at each finer level), which `ooc`'s factor walk reads;
    /// a version-2 index has none and the walk bounds those levels by the block's maximum.
    pub fine_maxima: bool,
    /// The finest level of the store's overview (`overview.bin`: every block's coarsest
    /// levels in one file, which a render's first frame and a store at a URL read instead of
    /// every block's file); `None` for a store baked before it.
    pub overview_levels: Option<u8>,
    /// Storage per block level (the out-of-core paper's non-redundant levels, Eq. 1-2), over
    /// every block of the store.
    pub levels: Vec<LevelStorage>,
    /// What `--error-px` uses for the out-of-core method on this store: its calibration
    /// (`ooc-calibration.txt`), or the shared one and what to expect from it.
    pub ooc_calibration: String,
}

/// One block level's storage over the whole store: the vertices new at that level (Qiu 2013
/// Eq. 1-2: `Offset(n)_end - Offset(n)_start + 1` per block), their stored (encoded, on disk)
/// bytes and their decoded bytes in memory.
#[derive(Debug, Serialize)]
pub(crate) struct LevelStorage {
    pub level: u8,
    /// Vertices new at this level, summed over the blocks.
    pub vertices: u64,
    /// Bytes of the level's payloads in the block files, summed over the blocks.
    pub disk_bytes: u64,
    /// Bytes of the level decoded in memory, summed over the blocks.
    pub decoded_bytes: u64,
}

/// Storage per level of `store`, summed over its blocks.
fn level_storage(store: &terrain_stream::Store) -> Vec<LevelStorage> {
    let levels = store.header().levels();
    let sample = terrain_stream::Header::SAMPLE_BYTES;
    let mut out: Vec<LevelStorage> = (0..levels)
        .map(|level| {
            let below = level.checked_sub(1).map_or(0, terrain_stream::BlockEntry::resident_bytes);
            let per_block = terrain_stream::BlockEntry::resident_bytes(level) - below;
            LevelStorage { level, vertices: 0, disk_bytes: 0, decoded_bytes: per_block }
        })
        .collect();
    let mut blocks = 0u64;
    for id in store.block_ids() {
        let Some(e) = store.entry(id) else { continue };
        blocks += 1;
        for (l, entry) in out.iter_mut().zip(&e.levels) {
            l.disk_bytes += u64::from(entry.len);
        }
    }
    for l in &mut out {
        l.decoded_bytes *= blocks;
        l.vertices = l.decoded_bytes / sample;
    }
    out
}

impl StoreReport {
    fn new(dir: &std::path::Path) -> anyhow::Result<Self> {
        use anyhow::Context;
        let store = terrain_app::ooc::open_store(dir)
            .with_context(|| format!("could not open the store {}", dir.display()))?;
        let h = store.header();
        // A remote store's index and tables are in its local mirror.
        let local = store.dir();
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        for id in store.block_ids() {
            if let Some(e) = store.entry(id) {
                lo = lo.min(e.min);
                hi = hi.max(e.max);
            }
        }
        let encoding = match h.encoding {
            terrain_stream::SampleEncoding::Quantized { step_m, offset_m } => {
                format!("integer steps of {step_m} m from {offset_m} m")
            }
            terrain_stream::SampleEncoding::F32 => "f32".to_string(),
        };
        // A remote store's are asked for (HEAD), not fetched.
        let mut tables = Vec::new();
        for f in [
            terrain_app::dss_scene::DSS_FILE,
            terrain_app::roughness_scene::ROUGHNESS_FILE,
            terrain_app::geomip_scene::GEOMIP_FILE,
            terrain_app::pvs_scene::SAMPLED_FILE,
            terrain_app::pvs_scene::CONSERVATIVE_FILE,
            terrain_stream::DECIMATION_FILE,
            terrain_app::tin_scene::TIN_TILES_FILE,
        ] {
            if store.has_side_file(f).with_context(|| format!("asking the store for {f}"))? {
                tables.push(f.to_string());
            }
        }
        // A remote paged index is not all in the mirror: its length from its head.
        let index = store.index_bytes().unwrap_or_else(|| {
            std::fs::metadata(local.join(terrain_stream::INDEX_FILE)).map_or(0, |m| m.len())
        });
        Ok(Self {
            store: dir.display().to_string(),
            width: h.width,
            height: h.height,
            crs: h.georef.crs.to_string(),
            spacing_m: h.georef.spacing_m.to_array(),
            block_side: h.block_side(),
            blocks: [h.blocks_x, h.blocks_y],
            encoding,
            max_error_m: h.max_error_m,
            min_m: lo,
            max_m: hi,
            bytes: index + store.blocks_bytes(),
            tables,
            dss_block_errors: store.has_dss_errors(),
            fine_maxima: store.has_fine_errors(),
            overview_levels: store.overview_levels(),
            levels: level_storage(&store),
            ooc_calibration: ooc_calibration_text(dir),
        })
    }

    fn to_text(&self) -> String {
        let mut s = String::new();
        s += &format!("store        {} (a baked block store)\n", self.store);
        s += &format!("size         {} x {} samples\n", self.width, self.height);
        s += &format!("crs          {}\n", self.crs);
        s += &format!("spacing (m)  {:.3} x {:.3} m\n", self.spacing_m[0], self.spacing_m[1]);
        s += &format!(
            "blocks       {} x {} of {}^2 vertices, {:.1} MiB\n",
            self.blocks[0],
            self.blocks[1],
            self.block_side,
            self.bytes as f64 / terrain_app::MIB
        );
        let exact = if self.max_error_m == 0.0 {
            "lossless".to_string()
        } else {
            format!("max vertical error {:.4} m", self.max_error_m)
        };
        s += &format!(
            "heights      {:.2} .. {:.2} m, {}, {exact}\n",
            self.min_m, self.max_m, self.encoding
        );
        let tables =
            if self.tables.is_empty() { "none".to_string() } else { self.tables.join(", ") };
        s += &format!("tables       {tables}\n");
        let dss = if self.dss_block_errors {
            "per block in the index"
        } else {
            "none (baked without them: dss-1, dss-2 and dss-strips refuse this store)"
        };
        s += &format!("dss errors   {dss}\n");
        let fine = if self.fine_maxima {
            "yes (ooc's factor walk is exact below the stored node levels)"
        } else {
            "none (an index of format version 2: ooc bounds nodes below the stored levels by the \
             block's per-level maximum and draws more triangles; bake again to add them)"
        };
        s += &format!("fine maxima  {fine}\n");
        let overview = match self.overview_levels {
            Some(top) => format!("levels 0-{top} of every block in one file (overview.bin)"),
            None => "none (baked before it: the coarse levels are read from every block's \
                     file; bake again for faster first frames)"
                .to_string(),
        };
        s += &format!("overview     {overview}\n");
        s += &format!("ooc --error-px {}\n", self.ooc_calibration);
        s += "levels       level: new vertices, stored MiB (decoded MiB)\n";
        for l in &self.levels {
            s += &format!(
                "             {}: {}, {:.3} ({:.3})\n",
                l.level,
                l.vertices,
                l.disk_bytes as f64 / terrain_app::MIB,
                l.decoded_bytes as f64 / terrain_app::MIB
            );
        }
        s
    }
}

/// What `--error-px` uses for `ooc` on the store in `dir`, in words: the store's calibration
/// (measured points, and where the default refinement's target lands), or the shared one with
/// its measured spread; a refused file says why.
fn ooc_calibration_text(dir: &std::path::Path) -> String {
    use terrain_app::method::registry::{ooc_p99_per_tau, ooc_p99_per_tau_spread};
    use terrain_app::ooc::OocConfig;
    use terrain_app::ooc_calibration::{self, FILE_NAME, split_name};
    let config = OocConfig::default();
    let split = split_name(config.split);
    let (lo, hi) = ooc_p99_per_tau_spread(config.split, config.max_segment_cells);
    let r = ooc_p99_per_tau(config.split, config.max_segment_cells);
    let floor = match config.max_segment_cells {
        0 => String::new(),
        cells => format!(", segments of at most {cells} cells"),
    };
    let shared = format!(
        "the shared calibration ({split}{floor}: tau = PX / {r}, the largest p99 per tau of four \
         DEMs; expect a p99 of {:.0}-{:.0} % of the target)",
        100.0 * lo / r,
        100.0 * hi / r
    );
    match ooc_calibration::of_store(dir) {
        Ok(Some(c)) => {
            let rr = c.refinement;
            let applies = if rr == config.refinement() {
                String::new()
            } else {
                format!(" (not the default refinement's: with the default, {shared})")
            };
            let points: Vec<String> =
                c.points().iter().map(|[t, p]| format!("{t}: {p:.2} px")).collect();
            format!(
                "{FILE_NAME}, measured under {} split, {}-cell patches, floor {} px{}; tau -> \
                 p99 {}; 1 px -> tau {:.3}{applies}",
                split_name(rr.split),
                rr.patch_cells,
                rr.cost_split_px,
                match rr.max_segment_cells {
                    0 => String::new(),
                    cells => format!(", segments of at most {cells} cells"),
                },
                points.join(", "),
                c.tau_for(1.0)
            )
        }
        Ok(None) => format!("{shared}; `terrain calibrate` measures this store's own"),
        Err(e) => format!("{shared}; {FILE_NAME} refused: {e}"),
    }
}

/// Runs `terrain info`.
pub(crate) fn run(args: &InfoArgs) -> anyhow::Result<()> {
    if let [one] = args.source.dem.as_slice()
        && terrain_app::ooc::is_store(one)
    {
        args.source.refuse_reading_options("a baked store (its heights are stored)")?;
        let report = StoreReport::new(one)?;
        if args.json {
            println!("{}", serde_json::to_string_pretty(&report)?);
        } else {
            print!("{}", report.to_text());
        }
        return Ok(());
    }
    let report = match args.source.load()? {
        Some(dem) => {
            let src = &dem.source;
            let mut name = src.path.display().to_string();
            if args.source.dem.len() > 1 {
                name = format!("mosaic of {} tiles starting at {name}", args.source.dem.len());
            }
            InfoReport::new(
                &dem.heightmap,
                name,
                format!("{:?}", src.format),
                src.sample_type.clone(),
                src.nodata,
            )
        }
        None => {
            let hm = terrain_core::synth::default_terrain();
            InfoReport::new(
                &hm,
                "embedded synthetic terrain (terrain_core::synth::default_terrain)".into(),
                "synthetic".into(),
                "float32 (generated)".into(),
                None,
            )
        }
    };
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print!("{}", report.to_text());
    }
    Ok(())
}
