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

/// Runs `terrain info`.
pub(crate) fn run(args: &InfoArgs) -> anyhow::Result<()> {
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
