//! Scattered elevation points (`x y z` text or CSV): the entropy paper's (Chen 2018) input.
//!
//! One point per line: three numbers separated by whitespace, commas or semicolons. Blank
//! lines and lines starting with `#` are skipped, and so is a first line that is not numeric
//! (a CSV header such as `x,y,z`). Extra columns after the third are ignored. The file is read
//! whole and parsed without allocating per line; every failure is a [`PointsError`] naming the
//! file, and the 1-based line for a bad line.

use std::path::{Path, PathBuf};

use glam::DVec3;

/// Why a points file could not be read.
#[derive(Debug, thiserror::Error)]
#[error("{}: {kind}", path.display())]
pub struct PointsError {
    /// The file.
    pub path: PathBuf,
    /// What went wrong.
    pub kind: PointsErrorKind,
}

/// The kinds of [`PointsError`].
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PointsErrorKind {
    /// The file could not be read.
    #[error("cannot read: {0}")]
    Io(#[from] std::io::Error),
    /// The file is not UTF-8 text.
    #[error("not a text file (invalid UTF-8 near byte {0})")]
    NotText(usize),
    /// A line does not hold three numbers.
    #[error("line {line}: {message}: {text:?}")]
    BadLine {
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        message: &'static str,
        /// The line (up to 80 characters).
        text: String,
    },
    /// Fewer points than needed.
    #[error("holds {0} point(s); at least 3 are needed")]
    TooFew(usize),
}

/// Reads an `x y z` / CSV points file (see the module doc).
pub fn read_points(path: &Path) -> Result<Vec<DVec3>, PointsError> {
    let err = |kind| PointsError { path: path.to_path_buf(), kind };
    let bytes = std::fs::read(path).map_err(|e| err(PointsErrorKind::Io(e)))?;
    let text =
        std::str::from_utf8(&bytes).map_err(|e| err(PointsErrorKind::NotText(e.valid_up_to())))?;
    parse_points(text).map_err(err)
}

/// Parses the text of a points file (see the module doc).
pub fn parse_points(text: &str) -> Result<Vec<DVec3>, PointsErrorKind> {
    let mut out = Vec::with_capacity(text.len() / 24);
    let mut first_data = true;
    for (k, line) in text.lines().enumerate() {
        let t = line.trim();
        if t.is_empty() || t.starts_with('#') {
            continue;
        }
        let mut fields = t
            .split(|c: char| c == ',' || c == ';' || c.is_ascii_whitespace())
            .filter(|f| !f.is_empty());
        let mut v = [0.0f64; 3];
        let mut bad: Option<&'static str> = None;
        for slot in &mut v {
            match fields.next() {
                None => {
                    bad = Some("fewer than three values");
                    break;
                }
                Some(f) => match f.parse::<f64>() {
                    Ok(x) if x.is_finite() => *slot = x,
                    Ok(_) => {
                        bad = Some("a value is not finite");
                        break;
                    }
                    Err(_) => {
                        bad = Some("a value is not a number");
                        break;
                    }
                },
            }
        }
        if let Some(message) = bad {
            if first_data && message == "a value is not a number" {
                // A header line.
                first_data = false;
                continue;
            }
            return Err(PointsErrorKind::BadLine {
                line: k + 1,
                message,
                text: t.chars().take(80).collect(),
            });
        }
        first_data = false;
        out.push(DVec3::from_array(v));
    }
    if out.len() < 3 {
        return Err(PointsErrorKind::TooFew(out.len()));
    }
    Ok(out)
}
