//! Where a command's terrain comes from: DEM files (one, or several tiles as a mosaic) with
//! the reading options users need for files that lack metadata, or the embedded synthetic terrain.

use std::path::PathBuf;

use anyhow::{Context, bail};
use clap::{Args, ValueEnum};
use terrain_core::dem::{self, Dem, Format, LoadOptions, RawSampleType, RawSpec};

/// Options shared by every command that reads terrain.
#[derive(Debug, Args)]
pub(crate) struct SourceArgs {
    /// DEM file(s); several adjacent tiles are joined into one mosaic. None: the embedded
    /// synthetic terrain. `render` and `fly` also take a store folder from `terrain bake`.
    pub dem: Vec<PathBuf>,
    /// Format, when it cannot be detected from the file (terrain-rgb, terrarium, raw).
    #[arg(long, value_enum)]
    pub format: Option<FormatArg>,
    /// No-data value, for files without a no-data tag (or to override it).
    #[arg(long, allow_hyphen_values = true)]
    pub nodata: Option<f64>,
    /// Metres per raw unit: for grey images and raw files, which have no vertical unit; for
    /// GeoTIFF (after its own scale/offset) and .hgt, a conversion of the file's vertical unit
    /// (e.g. 0.3048 for heights in feet), reported when used. Also a vertical exaggeration
    /// (e.g. 3) for every input, scattered points (`mesh --points`) included; for a baked store
    /// (`render`, `fly`, `view`) it exaggerates the stored heights as they are read, and every
    /// method's selection errors with them (a positive number).
    #[arg(long, default_value_t = 1.0)]
    pub vertical_scale: f64,
    /// Metres added after scaling (see --vertical-scale).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    pub vertical_offset: f64,
    /// Horizontal spacing in metres (default 1), for files without georeference (images, raw,
    /// GeoTIFF without one); refused for georeferenced files, whose own spacing is used.
    #[arg(long)]
    pub spacing: Option<f64>,
    /// The band of a multi-band GeoTIFF read as heights, from 1 (GDAL's numbering).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..))]
    pub band: u16,
    /// Raw files: WIDTHxHEIGHT:TYPE with TYPE one of i16, u16, f32 (little-endian, north row first).
    #[arg(long)]
    pub raw: Option<String>,
    /// Most memory reading a DEM may take (heights, void mask and decoding buffers, estimated
    /// from its declared size before anything is allocated): bytes, or a number with KiB, MiB,
    /// GiB or TiB. Files that would need more are refused.
    #[arg(long, default_value = "4GiB", value_parser = parse_memory)]
    pub max_memory: u64,
}

/// `--format` values.
#[derive(Debug, Clone, Copy, ValueEnum)]
pub(crate) enum FormatArg {
    /// GeoTIFF.
    Geotiff,
    /// SRTM .hgt.
    Hgt,
    /// 8/16-bit grey PNG or JPEG.
    Grey,
    /// Mapbox Terrain-RGB PNG.
    TerrainRgb,
    /// Terrarium PNG.
    Terrarium,
    /// Headerless raw samples (needs --raw).
    Raw,
}

/// `--max-memory`'s default, 4 GiB.
const DEFAULT_MAX_MEMORY: u64 = 4 << 30;

impl SourceArgs {
    /// The reading options these arguments describe.
    pub(crate) fn load_options(&self) -> anyhow::Result<LoadOptions> {
        let raw = self.raw.as_deref().map(parse_raw).transpose()?;
        let format = match self.format {
            None if raw.is_some() => Some(Format::Raw),
            None => None,
            Some(FormatArg::Geotiff) => Some(Format::GeoTiff),
            Some(FormatArg::Hgt) => Some(Format::Hgt),
            Some(FormatArg::Grey) => Some(Format::GreyImage),
            Some(FormatArg::TerrainRgb) => Some(Format::TerrainRgb),
            Some(FormatArg::Terrarium) => Some(Format::Terrarium),
            Some(FormatArg::Raw) => Some(Format::Raw),
        };
        if matches!(format, Some(Format::Raw)) && raw.is_none() {
            bail!("--format raw needs --raw WIDTHxHEIGHT:TYPE");
        }
        let spacing = self.spacing.unwrap_or(1.0);
        if !(spacing.is_finite() && (MIN_SPACING_M..=MAX_SPACING_M).contains(&spacing)) {
            bail!(
                "--spacing must be between {MIN_SPACING_M} and {MAX_SPACING_M} metres between \
                 samples, got {}",
                plain(spacing)
            );
        }
        if !self.vertical_scale.is_finite() || self.vertical_scale == 0.0 {
            bail!("--vertical-scale must be finite and non-zero, got {}", self.vertical_scale);
        }
        Ok(LoadOptions {
            format,
            nodata: self.nodata,
            vertical_scale: self.vertical_scale,
            vertical_offset: self.vertical_offset,
            spacing_m: spacing,
            spacing_given: self.spacing.is_some(),
            band: self.band,
            raw,
            max_memory_bytes: self.max_memory,
            ..LoadOptions::default()
        })
    }

    /// Refuses the reading options when the input is not a DEM file but `what` (a baked store,
    /// a scene folder), whose heights are already read: each given option is named. An option
    /// at its default value changes nothing and passes.
    pub(crate) fn refuse_reading_options(&self, what: &str) -> anyhow::Result<()> {
        self.refuse_reading_options_but(what, false)
    }

    /// A baked store's vertical exaggeration (`--vertical-scale`, applied as the store is
    /// read: `terrain_stream::Store::exaggerated`), refusing the other reading options as
    /// [`SourceArgs::refuse_reading_options`] does.
    pub(crate) fn store_exaggeration(&self) -> anyhow::Result<f64> {
        self.refuse_reading_options_but("a baked store (its heights are stored)", true)?;
        let s = self.vertical_scale;
        if !(s.is_finite() && s > 0.0) {
            bail!(
                "--vertical-scale over a baked store is a vertical exaggeration: a positive \
                 number, got {s}"
            );
        }
        Ok(s)
    }

    /// [`SourceArgs::refuse_reading_options`], `--vertical-scale` let through when
    /// `exaggeration` (a store's).
    fn refuse_reading_options_but(&self, what: &str, exaggeration: bool) -> anyhow::Result<()> {
        let given: Vec<&str> = [
            ("--format", self.format.is_some()),
            ("--nodata", self.nodata.is_some()),
            ("--vertical-scale", self.vertical_scale != 1.0 && !exaggeration),
            ("--vertical-offset", self.vertical_offset != 0.0),
            ("--spacing", self.spacing.is_some()),
            ("--band", self.band != 1),
            ("--raw", self.raw.is_some()),
            ("--max-memory", self.max_memory != DEFAULT_MAX_MEMORY),
        ]
        .iter()
        .filter(|(_, g)| *g)
        .map(|(name, _)| *name)
        .collect();
        // A store's or scene's heights were scaled when it was baked: say how to scale them.
        let rebake = if given.iter().any(|g| g.starts_with("--vertical")) {
            "; its heights are stored as baked: to convert them, bake it again from the DEM with \
             them (`terrain bake DEM --vertical-scale S -o FOLDER --overwrite`; a store's \
             --vertical-scale alone exaggerates it in render, fly and view)"
        } else {
            ""
        };
        match given.as_slice() {
            [] => Ok(()),
            [one] => bail!("{one} applies to reading a DEM file, not to {what}{rebake}"),
            many => {
                bail!("{} apply to reading a DEM file, not to {what}{rebake}", many.join(", "))
            }
        }
    }

    /// Reads the DEM(s) as [`SourceArgs::load`] does and refuses a grid no surface can be made
    /// of ([`check_surface`]): what `bake`, `render`, `fly`, `bench` and `mesh` read.
    pub(crate) fn load_surface(&self) -> anyhow::Result<Option<Dem>> {
        let Some(dem) = self.load()? else { return Ok(None) };
        let hm = &dem.heightmap;
        check_surface(
            &dem.source.path.display().to_string(),
            (hm.width() as u64, hm.height() as u64),
            hm.georef().spacing_m,
            Some((hm.min(), hm.max())),
            hm.georef().crs == terrain_core::Crs::Unknown,
        )?;
        Ok(Some(dem))
    }

    /// Reads the DEM(s); `None` when no file was given (the caller uses the embedded terrain).
    pub(crate) fn load(&self) -> anyhow::Result<Option<Dem>> {
        let options = self.load_options()?;
        let dem = match self.dem.as_slice() {
            [] => return Ok(None),
            [one] => dem::load(one, &options)?,
            many => dem::load_mosaic(many, &options).context("could not build the mosaic")?,
        };
        // Heights that look like a mistake: said, never changed.
        for w in &dem.warnings {
            eprintln!("warning: {w}");
        }
        Ok(Some(dem))
    }
}

/// Smallest `--spacing`, metres (1 mm: finer than any survey's grid).
pub(crate) const MIN_SPACING_M: f64 = 1e-3;
/// Largest `--spacing`, metres (1000 km: a global grid at one degree has 111 km).
pub(crate) const MAX_SPACING_M: f64 = 1e6;
/// Largest extent of a grid a surface is made of, metres (2.5 times the Earth's circumference).
pub(crate) const MAX_EXTENT_M: f64 = 1e8;
/// Largest height, metres (no terrain is within two orders of magnitude of it).
pub(crate) const MAX_ABS_HEIGHT_M: f64 = 1e6;

/// Refuses, before any work, a grid no surface can be made of: fewer than 2 x 2 samples (no
/// cell to draw, bake or mesh), a sample spacing under a millimetre or an extent beyond
/// `MAX_EXTENT_M` (a camera framing it would be at infinity), or heights beyond
/// `MAX_ABS_HEIGHT_M`. Says what is wrong, why, and which option sets it. `from_options`: the
/// spacing came from `--spacing` (the file has no georeference).
pub(crate) fn check_surface(
    name: &str,
    (width, height): (u64, u64),
    spacing_m: glam::DVec2,
    heights: Option<(f32, f32)>,
    from_options: bool,
) -> anyhow::Result<()> {
    if width < 2 || height < 2 {
        bail!(
            "{name}: the grid is {width} x {height} samples; a surface needs at least 2 x 2 \
             samples (one cell) to be drawn, baked or meshed"
        );
    }
    let spacing = if from_options { "--spacing" } else { "the file's georeference" };
    let extent = glam::dvec2((width - 1) as f64, (height - 1) as f64) * spacing_m;
    if !(spacing_m.min_element() >= MIN_SPACING_M && extent.max_element() <= MAX_EXTENT_M) {
        bail!(
            "{name}: {width} x {height} samples at {} x {} m spacing span {:.4e} x {:.4e} m; a \
             terrain spans at most {MAX_EXTENT_M:e} m with samples at least {MIN_SPACING_M} m \
             apart (a camera framing it would be at infinity): check the spacing ({spacing})",
            plain(spacing_m.x),
            plain(spacing_m.y),
            extent.x,
            extent.y
        );
    }
    if let Some((lo, hi)) = heights
        && f64::from(lo.abs().max(hi.abs())) > MAX_ABS_HEIGHT_M
    {
        bail!(
            "{name}: heights from {} to {} m; no terrain reaches {MAX_ABS_HEIGHT_M:e} m: check \
             --vertical-scale and --vertical-offset (or the file's sample type and nodata)",
            plain(f64::from(lo)),
            plain(f64::from(hi))
        );
    }
    Ok(())
}

/// A number as users write it: plain, or in exponent form when very large or small.
fn plain(x: f64) -> String {
    if x != 0.0 && !(1e-3..1e6).contains(&x.abs()) { format!("{x:e}") } else { format!("{x}") }
}

/// Parses `--max-memory`: bytes, or a number with a binary unit (KiB, MiB, GiB, TiB).
pub(crate) fn parse_memory(s: &str) -> Result<u64, String> {
    let t = s.trim();
    let split = t.find(|c: char| !(c.is_ascii_digit() || c == '.')).unwrap_or(t.len());
    let (num, unit) = t.split_at(split);
    let shift = match unit.trim().to_ascii_lowercase().as_str() {
        "" | "b" => 0,
        "kib" => 10,
        "mib" => 20,
        "gib" => 30,
        "tib" => 40,
        other => {
            return Err(format!(
                "unit `{other}` in `{s}`: give bytes or a number with KiB, MiB, GiB or TiB \
                 (binary units, e.g. 8GiB)"
            ));
        }
    };
    let v: f64 = num.parse().map_err(|_| format!("`{s}` is not a size such as 4GiB"))?;
    let bytes = v * (1u64 << shift) as f64;
    if !(bytes.is_finite() && bytes >= 1.0 && bytes < u64::MAX as f64) {
        return Err(format!("`{s}` is not a positive size below 16 EiB"));
    }
    Ok(bytes as u64)
}

fn parse_raw(s: &str) -> anyhow::Result<RawSpec> {
    let bad = || format!("--raw expects WIDTHxHEIGHT:TYPE (e.g. 1024x768:f32), got `{s}`");
    let (dims, ty) = s.split_once(':').with_context(bad)?;
    let (w, h) = dims.split_once(['x', 'X']).with_context(bad)?;
    let width: u64 = w.trim().parse().with_context(bad)?;
    let height: u64 = h.trim().parse().with_context(bad)?;
    let sample = match ty.trim().to_ascii_lowercase().as_str() {
        "i16" | "int16" => RawSampleType::I16,
        "u16" | "uint16" => RawSampleType::U16,
        "f32" | "float32" => RawSampleType::F32,
        _ => bail!("{}; TYPE must be i16, u16 or f32", bad()),
    };
    Ok(RawSpec { width, height, sample })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn max_memory_parses_binary_units_and_rejects_others() {
        assert_eq!(parse_memory("4GiB").unwrap(), 4 << 30);
        assert_eq!(parse_memory("512 MiB").unwrap(), 512 << 20);
        assert_eq!(parse_memory("1.5kib").unwrap(), 1536);
        assert_eq!(parse_memory("1000").unwrap(), 1000);
        for bad in ["4GB", "-1GiB", "0", "GiB", "1e30TiB"] {
            let e = parse_memory(bad).unwrap_err();
            assert!(e.contains(bad.trim_start_matches('-')), "{bad}: {e}");
        }
    }

    #[test]
    fn max_memory_reaches_the_load_options() {
        use clap::Parser;
        #[derive(Parser)]
        struct Cli {
            #[command(flatten)]
            source: SourceArgs,
        }
        let default = Cli::try_parse_from(["t"]).unwrap().source.load_options().unwrap();
        assert_eq!(default.max_memory_bytes, dem::DEFAULT_MAX_MEMORY_BYTES);
        let cli = Cli::try_parse_from(["t", "--max-memory", "64MiB"]).unwrap();
        assert_eq!(cli.source.load_options().unwrap().max_memory_bytes, 64 << 20);
    }

    #[test]
    fn band_and_spacing_reach_the_load_options() {
        use clap::Parser;
        #[derive(Parser)]
        struct Cli {
            #[command(flatten)]
            source: SourceArgs,
        }
        let default = Cli::try_parse_from(["t"]).unwrap().source.load_options().unwrap();
        assert_eq!((default.band, default.spacing_given, default.spacing_m), (1, false, 1.0));
        let cli = Cli::try_parse_from(["t", "--band", "3", "--spacing", "30"]).unwrap();
        let o = cli.source.load_options().unwrap();
        assert_eq!((o.band, o.spacing_given, o.spacing_m), (3, true, 30.0));
        assert!(Cli::try_parse_from(["t", "--band", "0"]).is_err(), "bands count from 1");
    }

    #[test]
    fn raw_spec_parses_and_rejects() {
        let r = parse_raw("1024x768:f32").unwrap();
        assert_eq!((r.width, r.height, r.sample), (1024, 768, RawSampleType::F32));
        assert_eq!(parse_raw("3X2:i16").unwrap().sample, RawSampleType::I16);
        for bad in ["1024x768", "axb:f32", "10x10:f64", "10:f32"] {
            let e = parse_raw(bad).unwrap_err().to_string();
            assert!(e.contains(bad), "{e}");
        }
    }
}
