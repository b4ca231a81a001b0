//! One fuzz case: which reader runs on which mutated files with which options, how it is
//! written to a folder (`case.txt` and the files) so `--replay` runs it again, and the DEM
//! readers' side of running it (terrain-core's `load`, `load_mosaic` and `RowReader`).

use std::fmt::Write as _;
use std::path::Path;

use terrain_core::dem::{
    Format, LoadOptions, RawSampleType, RawSpec, RowReader, load, load_mosaic,
};

/// The reader a case runs.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Target {
    /// `dem::load` of the first file.
    Load(Opts),
    /// `RowReader::open` of the first file, then bands of rows and void rows.
    Rows(Opts),
    /// `dem::load_mosaic` of every file.
    Mosaic(Opts),
    /// Store `n` of the fixture with the case's files replacing its own: open, read every
    /// block, select, load the tables.
    Store(usize),
}

impl Target {
    /// Short name for the statistics.
    pub(crate) fn name(&self) -> &'static str {
        match self {
            Target::Load(_) => "load",
            Target::Rows(_) => "rows",
            Target::Mosaic(_) => "mosaic",
            Target::Store(_) => "store",
        }
    }
}

/// The `LoadOptions` a case varies (the memory limit is the run's).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Opts {
    pub format: Option<Format>,
    pub raw: Option<RawSpec>,
    pub nodata: Option<f64>,
    pub vertical_scale: f64,
}

impl Opts {
    pub(crate) fn load_options(&self, max_memory_bytes: u64) -> LoadOptions {
        LoadOptions {
            format: self.format,
            raw: self.raw,
            nodata: self.nodata,
            vertical_scale: self.vertical_scale,
            max_memory_bytes,
            ..LoadOptions::default()
        }
    }
}

/// A case: the target, the files (relative path and bytes; a DEM target reads the first), and
/// where it came from.
#[derive(Debug, Clone)]
pub(crate) struct Case {
    pub target: Target,
    pub files: Vec<(String, Vec<u8>)>,
    pub seed: u64,
    pub iteration: u64,
    /// The seed file and the mutations applied.
    pub what: String,
}

const FORMATS: [(&str, Format); 6] = [
    ("geotiff", Format::GeoTiff),
    ("hgt", Format::Hgt),
    ("grey", Format::GreyImage),
    ("terrain-rgb", Format::TerrainRgb),
    ("terrarium", Format::Terrarium),
    ("raw", Format::Raw),
];
const SAMPLES: [(&str, RawSampleType); 3] =
    [("i16", RawSampleType::I16), ("u16", RawSampleType::U16), ("f32", RawSampleType::F32)];

/// The file that describes a saved case in its folder.
pub(crate) const CASE_FILE: &str = "case.txt";

impl Case {
    /// Writes the case into folder `dir` (created; emptied first): `case.txt` and the files.
    pub(crate) fn save(&self, dir: &Path) -> std::io::Result<()> {
        if dir.exists() {
            std::fs::remove_dir_all(dir)?;
        }
        std::fs::create_dir_all(dir)?;
        let mut t = String::new();
        let _ = writeln!(
            t,
            "# terrain-fuzz case: replay with `cargo xtask fuzz --replay {}`",
            dir.display()
        );
        let _ = writeln!(t, "seed={}\niteration={}", self.seed, self.iteration);
        let _ = writeln!(t, "what={}", self.what.replace('\n', " "));
        let _ = writeln!(t, "target={}", self.target.name());
        match &self.target {
            Target::Store(n) => {
                let _ = writeln!(t, "store={n}");
            }
            Target::Load(o) | Target::Rows(o) | Target::Mosaic(o) => {
                if let Some(f) = o.format {
                    let name = FORMATS.iter().find(|(_, g)| *g == f).map_or("?", |(n, _)| n);
                    let _ = writeln!(t, "format={name}");
                }
                if let Some(r) = o.raw {
                    let s = SAMPLES.iter().find(|(_, g)| *g == r.sample).map_or("?", |(n, _)| n);
                    let _ = writeln!(t, "raw={},{},{s}", r.width, r.height);
                }
                if let Some(v) = o.nodata {
                    let _ = writeln!(t, "nodata={v:?}");
                }
                let _ = writeln!(t, "vertical_scale={:?}", o.vertical_scale);
            }
        }
        for (name, bytes) in &self.files {
            let _ = writeln!(t, "file={name}");
            let p = dir.join(name);
            if let Some(parent) = p.parent() {
                std::fs::create_dir_all(parent)?;
            }
            std::fs::write(p, bytes)?;
        }
        std::fs::write(dir.join(CASE_FILE), t)
    }

    /// Reads a case saved by [`Case::save`].
    pub(crate) fn load(dir: &Path) -> Result<Case, String> {
        let text = std::fs::read_to_string(dir.join(CASE_FILE))
            .map_err(|e| format!("{}: {e}", dir.join(CASE_FILE).display()))?;
        let (mut seed, mut iteration, mut what, mut target) = (0, 0, String::new(), "load");
        let mut store = 0;
        let mut opts = Opts { format: None, raw: None, nodata: None, vertical_scale: 1.0 };
        let mut files = Vec::new();
        let bad = |line: &str| format!("{}: cannot read the line `{line}`", dir.display());
        for line in text.lines().filter(|l| !l.starts_with('#') && !l.is_empty()) {
            let (k, v) = line.split_once('=').ok_or_else(|| bad(line))?;
            match k {
                "seed" => seed = v.parse().map_err(|_| bad(line))?,
                "iteration" => iteration = v.parse().map_err(|_| bad(line))?,
                "what" => what = v.to_string(),
                "target" => {
                    target = ["load", "rows", "mosaic", "store"]
                        .into_iter()
                        .find(|t| *t == v)
                        .ok_or_else(|| bad(line))?
                }
                "store" => store = v.parse().map_err(|_| bad(line))?,
                "format" => {
                    let f = FORMATS.iter().find(|(n, _)| *n == v).ok_or_else(|| bad(line))?;
                    opts.format = Some(f.1);
                }
                "raw" => {
                    let p: Vec<&str> = v.split(',').collect();
                    let s = SAMPLES
                        .iter()
                        .find(|(n, _)| Some(n) == p.get(2))
                        .ok_or_else(|| bad(line))?;
                    opts.raw = Some(RawSpec {
                        width: p[0].parse().map_err(|_| bad(line))?,
                        height: p[1].parse().map_err(|_| bad(line))?,
                        sample: s.1,
                    });
                }
                "nodata" => opts.nodata = Some(v.parse().map_err(|_| bad(line))?),
                "vertical_scale" => opts.vertical_scale = v.parse().map_err(|_| bad(line))?,
                "file" => {
                    let bytes = std::fs::read(dir.join(v))
                        .map_err(|e| format!("{}: {e}", dir.join(v).display()))?;
                    files.push((v.to_string(), bytes));
                }
                _ => return Err(bad(line)),
            }
        }
        let target = match target {
            "load" => Target::Load(opts),
            "rows" => Target::Rows(opts),
            "mosaic" => Target::Mosaic(opts),
            _ => Target::Store(store),
        };
        if files.is_empty() {
            return Err(format!("{}: the case names no file", dir.display()));
        }
        Ok(Case { target, files, seed, iteration, what })
    }
}

/// Bytes a band of rows may take in the harness's own buffers (heights and voids).
const BAND_BYTES: u64 = 64 << 20;

/// Runs a DEM target on the files written in `dir`. `Ok` with what was read, or the reader's
/// error as text (a refusal: the expected outcome for most mutants).
pub(crate) fn run_dem(
    target: &Target,
    dir: &Path,
    files: &[String],
    max_memory_bytes: u64,
) -> Result<String, String> {
    let first = dir.join(&files[0]);
    match target {
        Target::Load(o) => {
            let dem = load(&first, &o.load_options(max_memory_bytes)).map_err(|e| e.to_string())?;
            let hm = &dem.heightmap;
            Ok(format!("{} x {} ({} warnings)", hm.width(), hm.height(), dem.warnings.len()))
        }
        Target::Mosaic(o) => {
            let paths: Vec<_> = files.iter().map(|f| dir.join(f)).collect();
            let dem = load_mosaic(&paths, &o.load_options(max_memory_bytes))
                .map_err(|e| e.to_string())?;
            Ok(format!("{} x {}", dem.heightmap.width(), dem.heightmap.height()))
        }
        Target::Rows(o) => {
            let r = RowReader::open(&first, &o.load_options(max_memory_bytes))
                .map_err(|e| e.to_string())?;
            let (w, h) = (r.width(), r.height());
            let _ = r.warnings();
            // Bands at the south edge, the middle and the north edge, as large as the
            // harness's buffer budget allows (a hostile width can make one row too large).
            let rows = (BAND_BYTES / (5 * w.max(1))).min(h).min(64);
            if rows == 0 {
                return Ok(format!("{w} x {h}: rows too wide to read here"));
            }
            let n = (w * rows) as usize;
            let (mut heights, mut voids) = (vec![0f32; n], vec![false; n]);
            for j0 in [0, (h - rows) / 2, h - rows] {
                r.read_rows(j0, rows as usize, &mut heights, &mut voids)
                    .map_err(|e| e.to_string())?;
                r.read_void_rows(j0, rows as usize, &mut voids).map_err(|e| e.to_string())?;
            }
            Ok(format!("{w} x {h}, {} zero-filled", r.zero_filled()))
        }
        Target::Store(_) => unreachable!("store cases run in crate::store"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_saved_case_reads_back_the_same() {
        let dir = std::env::temp_dir().join(format!("terrain-fuzz-case-{}", std::process::id()));
        let opts = Opts {
            format: Some(Format::Raw),
            raw: Some(RawSpec { width: 3, height: 2, sample: RawSampleType::U16 }),
            nodata: Some(f64::NAN),
            vertical_scale: 1e35,
        };
        for target in [Target::Rows(opts.clone()), Target::Store(1)] {
            let case = Case {
                target: target.clone(),
                files: vec![("a.u16".into(), vec![1, 2, 3]), ("blocks/b.tsb".into(), vec![9])],
                seed: 5,
                iteration: 77,
                what: "two\nlines".into(),
            };
            case.save(&dir).unwrap();
            let back = Case::load(&dir).unwrap();
            assert_eq!((back.seed, back.iteration, back.files), (5, 77, case.files));
            assert_eq!(back.what, "two lines");
            match (&back.target, &target) {
                (Target::Rows(a), Target::Rows(b)) => {
                    assert_eq!(
                        (a.format, a.raw, a.vertical_scale),
                        (b.format, b.raw, b.vertical_scale)
                    );
                    assert!(a.nodata.unwrap().is_nan());
                }
                (a, b) => assert_eq!(a, b),
            }
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
