//! Reading a validation set laid out as `../shared/validation/` (its README gives the layout and the scoring):
//! `extract/NAME.png` with `NAME.truth.csv` (`row,stripe,x`) and `NAME.sensor.toml`; `calib/plane_HH.HH.png` with
//! `sensor.toml`; `scans/NAME/` with `frames/`, `sensor.toml`, `heightmap.tiff`, `heightmap.json` and
//! `defects.json`.

use crate::IoError;
use std::path::{Path, PathBuf};

/// Largest truth file read, bytes (a million centres is ~20 MB).
pub const MAX_TRUTH_BYTES: u64 = 64 << 20;

/// One true stripe centre: image row, stripe index, sub-pixel column.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrueCentre {
    /// Image row.
    pub row: u32,
    /// Stripe (sheet) index.
    pub stripe: u32,
    /// Sub-pixel column (pixel centres at integers).
    pub x: f64,
}

/// One frame of a validation set's `extract/` folder.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ExtractCase {
    /// The frame's name (file stem).
    pub name: String,
    /// The image.
    pub image: PathBuf,
    /// Its true centres.
    pub truth: PathBuf,
    /// Its nominal sensor, when present.
    pub sensor: Option<PathBuf>,
}

/// The frames of `dir` (an `extract/` folder): every `NAME.png` that has a `NAME.truth.csv`, in name order.
pub fn extract_cases(dir: &Path) -> Result<Vec<ExtractCase>, IoError> {
    let mut out = Vec::new();
    for p in crate::files::read_dir(dir)? {
        let Some(name) = p
            .file_name()
            .and_then(|n| n.to_str())
            .and_then(|n| n.strip_suffix(".png"))
        else {
            continue;
        };
        let truth = dir.join(format!("{name}.truth.csv"));
        if !truth.is_file() {
            continue;
        }
        let sensor = dir.join(format!("{name}.sensor.toml"));
        out.push(ExtractCase {
            name: name.to_string(),
            image: p.clone(),
            truth,
            sensor: sensor.is_file().then_some(sensor),
        });
    }
    Ok(out)
}

/// Reads a `row,stripe,x` truth file; refuses, by line and field, anything that is not one.
pub fn read_true_centres(path: &Path) -> Result<Vec<TrueCentre>, IoError> {
    let meta = std::fs::metadata(path).map_err(|source| IoError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    if meta.len() > MAX_TRUTH_BYTES {
        return Err(IoError::Invalid {
            path: path.to_path_buf(),
            line: None,
            field: "size".into(),
            message: format!(
                "{} bytes is more than the {MAX_TRUTH_BYTES} a truth file may hold",
                meta.len()
            ),
        });
    }
    let text = std::fs::read_to_string(path).map_err(|source| IoError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    parse_true_centres(&text).map_err(|(line, column, message)| IoError::Syntax {
        path: path.to_path_buf(),
        line,
        column,
        message,
    })
}

/// Parses the text of a truth file; an error is (line, column, message), 1-based.
pub fn parse_true_centres(text: &str) -> Result<Vec<TrueCentre>, (usize, usize, String)> {
    let mut lines = text.lines().enumerate();
    match lines.next() {
        Some((_, h)) if h.trim() == "row,stripe,x" => {}
        Some((_, h)) => {
            return Err((
                1,
                1,
                format!("header `{}`: expected `row,stripe,x`", h.trim()),
            ));
        }
        None => {
            return Err((
                1,
                1,
                "empty file: expected the header `row,stripe,x`".into(),
            ));
        }
    }
    let mut out = Vec::new();
    for (i, line) in lines {
        let n = i + 1;
        if line.trim().is_empty() {
            continue;
        }
        let fields: Vec<&str> = line.split(',').collect();
        if fields.len() != 3 {
            return Err((
                n,
                1,
                format!("{} fields: expected 3 (row,stripe,x)", fields.len()),
            ));
        }
        let col = |k: usize| 1 + fields[..k].iter().map(|f| f.len() + 1).sum::<usize>();
        let row = fields[0]
            .trim()
            .parse::<u32>()
            .map_err(|_| (n, col(0), format!("row `{}`: not a row number", fields[0])))?;
        let stripe = fields[1].trim().parse::<u32>().map_err(|_| {
            (
                n,
                col(1),
                format!("stripe `{}`: not a stripe index", fields[1]),
            )
        })?;
        let x = fields[2]
            .trim()
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| (n, col(2), format!("x `{}`: not a finite number", fields[2])))?;
        out.push(TrueCentre { row, stripe, x });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn truth_files_parse_and_bad_ones_are_refused_by_line_and_column() {
        let ok = parse_true_centres("row,stripe,x\n0,1,12.5\n\n3,0,7\n").expect("valid");
        assert_eq!(ok.len(), 2);
        assert_eq!(
            ok[0],
            TrueCentre {
                row: 0,
                stripe: 1,
                x: 12.5
            }
        );
        assert_eq!(parse_true_centres("a,b\n").expect_err("header").0, 1);
        let e = parse_true_centres("row,stripe,x\n0,1,2\n4,x,2\n").expect_err("stripe");
        assert_eq!((e.0, e.1), (3, 3), "{e:?}");
        let e = parse_true_centres("row,stripe,x\n0,1,NaN\n").expect_err("NaN");
        assert_eq!((e.0, e.1), (2, 5), "{e:?}");
        assert!(parse_true_centres("row,stripe,x\n1,2\n").is_err());
        assert!(parse_true_centres("").is_err());
    }

    proptest::proptest! {
        #[test]
        fn any_text_is_parsed_or_refused_never_panics(s in "\\PC{0,200}") {
            let text = format!("row,stripe,x\n{s}");
            if let Err((line, col, _)) = parse_true_centres(&text) {
                proptest::prop_assert!(line >= 2 && col >= 1);
            }
        }
    }
}
