//! Reading a validation set laid out as `../shared/validation/` (its README gives the layout and the scoring):
//! `extract/NAME.png` with `NAME.truth.csv` (`row,stripe,x`) and `NAME.sensor.toml`; `calib/plane_HH.HH.png` with
//! `sensor.toml`; `scans/NAME/` with `frames/`, `sensor.toml`, `heightmap.tiff`, `heightmap.json` and
//! `defects.json`.

use crate::IoError;
use serde::Deserialize;
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

/// One scan of a validation set's `scans/` folder.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ScanCase {
    /// The scan's name (folder name).
    pub name: String,
    /// Its folder (holding `frames/`, `sensor.toml`, `heightmap.json`, `heightmap.tiff`, `defects.json`).
    pub dir: PathBuf,
}

impl ScanCase {
    /// The folder of frames.
    pub fn frames(&self) -> PathBuf {
        self.dir.join("frames")
    }
    /// The nominal sensor.
    pub fn sensor(&self) -> PathBuf {
        self.dir.join("sensor.toml")
    }
}

/// The scans of `dir` (a `scans/` folder): every sub-folder holding `frames/` and `heightmap.json`, in name order.
pub fn scan_cases(dir: &Path) -> Result<Vec<ScanCase>, IoError> {
    let mut out = Vec::new();
    let dirs = crate::files::read_dir(dir)?
        .into_iter()
        .filter(|p| p.join("frames").is_dir() && p.join("heightmap.json").is_file());
    for d in dirs {
        let name = d
            .file_name()
            .and_then(|n| n.to_str())
            .unwrap_or_default()
            .to_string();
        out.push(ScanCase { name, dir: d });
    }
    Ok(out)
}

/// A true height map: float32 heights (mm) on a square grid in the part coordinates of frame 0; column `i` at
/// `x = origin_mm[0] + i * spacing_mm`, row `j` at `y = origin_mm[1] + j * spacing_mm`.
#[derive(Debug, Clone, PartialEq)]
pub struct HeightMap {
    /// Position of cell (0, 0), mm.
    pub origin_mm: [f64; 2],
    /// Cell size, mm.
    pub spacing_mm: f64,
    /// Columns (along x).
    pub cols: usize,
    /// Rows (along y).
    pub rows: usize,
    /// Heights, row-major.
    pub z: Vec<f32>,
}

impl HeightMap {
    /// The height of cell (i, j).
    pub fn cell(&self, i: usize, j: usize) -> f64 {
        f64::from(self.z[j * self.cols + i])
    }

    /// Fractional cell coordinates of (x, y).
    fn grid(&self, x: f64, y: f64) -> (f64, f64) {
        (
            (x - self.origin_mm[0]) / self.spacing_mm,
            (y - self.origin_mm[1]) / self.spacing_mm,
        )
    }

    /// The true height at (x, y) mm, bilinear between the four cells around it; `None` outside the map or where
    /// a neighbouring cell is not finite.
    pub fn at(&self, x: f64, y: f64) -> Option<f64> {
        let (gx, gy) = self.grid(x, y);
        if !(gx >= 0.0 && gy >= 0.0) {
            return None;
        }
        let (i, j) = (gx.floor() as usize, gy.floor() as usize);
        if i + 1 >= self.cols || j + 1 >= self.rows {
            return None;
        }
        let (fx, fy) = (gx - i as f64, gy - j as f64);
        let v = (1.0 - fy) * ((1.0 - fx) * self.cell(i, j) + fx * self.cell(i + 1, j))
            + fy * ((1.0 - fx) * self.cell(i, j + 1) + fx * self.cell(i + 1, j + 1));
        v.is_finite().then_some(v)
    }

    /// Per cell, whether the true surface varies by less than `step_mm` within `radius_mm` of it (the largest
    /// minus the smallest height over the square of that half-width).
    pub fn smooth_mask(&self, radius_mm: f64, step_mm: f64) -> Vec<bool> {
        let r = (radius_mm / self.spacing_mm).round().max(0.0) as usize;
        let (w, h) = (self.cols, self.rows);
        // Separable running max and min: along rows, then along columns.
        let window = |src: &[f32], len: usize, stride: usize, lines: usize, line_stride: usize| {
            let mut lo = vec![0f32; src.len()];
            let mut hi = vec![0f32; src.len()];
            for l in 0..lines {
                for k in 0..len {
                    let (a, b) = (k.saturating_sub(r), (k + r).min(len - 1));
                    let (mut mn, mut mx) = (f32::INFINITY, f32::NEG_INFINITY);
                    for t in a..=b {
                        let v = src[l * line_stride + t * stride];
                        mn = mn.min(v);
                        mx = mx.max(v);
                    }
                    lo[l * line_stride + k * stride] = mn;
                    hi[l * line_stride + k * stride] = mx;
                }
            }
            (lo, hi)
        };
        let (lo1, hi1) = window(&self.z, w, 1, h, w);
        let (lo, _) = window(&lo1, h, w, w, 1);
        let (_, hi) = window(&hi1, h, w, w, 1);
        lo.iter()
            .zip(&hi)
            .map(|(a, b)| a.is_finite() && b.is_finite() && f64::from(b - a) < step_mm)
            .collect()
    }
}

/// Reads `heightmap.json` and the `heightmap.tiff` beside it.
pub fn read_height_map(json_path: &Path) -> Result<HeightMap, IoError> {
    let text = crate::files::read_text(json_path)?;
    let doc: serde_json::Value = serde_json::from_str(&text).map_err(|e| IoError::Syntax {
        path: json_path.to_path_buf(),
        line: e.line(),
        column: e.column(),
        message: e.to_string(),
    })?;
    let invalid = |field: &str, message: &str| IoError::Invalid {
        path: json_path.to_path_buf(),
        line: None,
        field: field.into(),
        message: message.into(),
    };
    let size = |field: &str| {
        doc.get(field)
            .and_then(serde_json::Value::as_u64)
            .filter(|v| (2..=1 << 15).contains(v))
            .map(|v| v as usize)
            .ok_or_else(|| invalid(field, "must be a whole number of cells from 2 to 32768"))
    };
    let (rows, cols) = (size("rows")?, size("cols")?);
    let spacing_mm = doc
        .get("spacing_mm")
        .and_then(serde_json::Value::as_f64)
        .filter(|v| v.is_finite() && *v > 0.0)
        .ok_or_else(|| invalid("spacing_mm", "must be a positive number (mm)"))?;
    let origin: Vec<f64> = doc
        .get("origin_mm")
        .and_then(serde_json::Value::as_array)
        .map(|a| a.iter().filter_map(serde_json::Value::as_f64).collect())
        .unwrap_or_default();
    let [ox, oy] = origin[..] else {
        return Err(invalid("origin_mm", "must be two numbers [x, y] (mm)"));
    };
    if !(ox.is_finite() && oy.is_finite()) {
        return Err(invalid(
            "origin_mm",
            "must be two finite numbers [x, y] (mm)",
        ));
    }
    let tiff = json_path.with_extension("tiff");
    let z = crate::report::read_layer(&tiff, json_path, cols, rows, "heights")?;
    Ok(HeightMap {
        origin_mm: [ox, oy],
        spacing_mm,
        cols,
        rows,
        z,
    })
}

/// One defect put into a validation part (`defects.json`).
#[derive(Debug, Clone, PartialEq, Deserialize)]
pub struct TrueDefect {
    /// `bump`, `dent`, `hole`, ...
    pub kind: String,
    /// Centre x, mm (part coordinates of frame 0).
    pub x_mm: f64,
    /// Centre y, mm.
    pub y_mm: f64,
    /// Radius, mm.
    pub radius_mm: f64,
    /// Depth (or height), mm.
    pub depth_mm: f64,
}

/// Reads `defects.json` (a list of [`TrueDefect`]).
pub fn read_true_defects(path: &Path) -> Result<Vec<TrueDefect>, IoError> {
    let text = crate::files::read_text(path)?;
    serde_json::from_str(&text).map_err(|e| IoError::Syntax {
        path: path.to_path_buf(),
        line: e.line(),
        column: e.column(),
        message: format!("{e} (expected a list of {{kind, x_mm, y_mm, radius_mm, depth_mm}})"),
    })
}

/// A scan's points scored against its true height map, as the validation README says.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct HeightScore {
    /// Points inside the map.
    pub points: usize,
    /// Points outside the map (not scored).
    pub outside: usize,
    /// Points more than [`GROSS_MM`] off the true height.
    pub gross: usize,
    /// RMS height error (mm) over the points on smooth parts of the part (not gross).
    pub rms_mm: f64,
    /// Points that RMS is over.
    pub smooth_points: usize,
    /// Share of the smooth part cells with a point within [`COVER_MM`] (in x, y).
    pub coverage: f64,
}

impl HeightScore {
    /// Gross errors over the points scored.
    pub fn gross_rate(&self) -> f64 {
        self.gross as f64 / self.points.max(1) as f64
    }
}

/// A point farther than this from the true height is a gross error, mm.
pub const GROSS_MM: f64 = 0.5;
/// A smooth cell is covered by a point within this distance, mm.
pub const COVER_MM: f64 = 0.3;
/// A cell is smooth when the true surface varies by less than [`SMOOTH_STEP_MM`] within this radius, mm.
pub const SMOOTH_RADIUS_MM: f64 = 1.0;
/// See [`SMOOTH_RADIUS_MM`], mm.
pub const SMOOTH_STEP_MM: f64 = 0.25;
/// A cell is on the part when its true height is above this, mm (the belt is at 0).
pub const PART_MM: f64 = 0.05;

/// [`score_heights`] of every point of a scan's profiles.
pub fn score_profiles(
    map: &HeightMap,
    profiles: &[stripe3d_core::accumulate::Profile],
) -> HeightScore {
    let points: Vec<[f64; 3]> = profiles
        .iter()
        .flat_map(|p| &p.points)
        .map(|p| [p.x_mm, p.y_mm, p.z_mm])
        .collect();
    score_heights(map, &points)
}

/// Scores points `(x, y, z)` mm against `map`: gross errors over all points, RMS over the (non-gross) points on
/// smooth parts of the part, coverage of the smooth part cells.
pub fn score_heights(map: &HeightMap, points: &[[f64; 3]]) -> HeightScore {
    let smooth = map.smooth_mask(SMOOTH_RADIUS_MM, SMOOTH_STEP_MM);
    let on_part = |k: usize| smooth[k] && f64::from(map.z[k]) > PART_MM;
    let mut covered = vec![false; map.z.len()];
    let reach = (COVER_MM / map.spacing_mm).ceil() as i64;
    let mut s = HeightScore::default();
    let mut sq = 0.0;
    for &[x, y, z] in points {
        let Some(t) = map.at(x, y) else {
            s.outside += 1;
            continue;
        };
        s.points += 1;
        let e = z - t;
        if e.abs() > GROSS_MM {
            s.gross += 1;
        }
        let (gx, gy) = map.grid(x, y);
        let (ci, cj) = (gx.round() as i64, gy.round() as i64);
        let k = cj as usize * map.cols + ci as usize;
        if k < map.z.len() && on_part(k) && e.abs() <= GROSS_MM {
            sq += e * e;
            s.smooth_points += 1;
        }
        for dj in -reach..=reach {
            for di in -reach..=reach {
                let (i, j) = (ci + di, cj + dj);
                if i < 0 || j < 0 || i as usize >= map.cols || j as usize >= map.rows {
                    continue;
                }
                let (dx, dy) = (i as f64 - gx, j as f64 - gy);
                if (dx * dx + dy * dy).sqrt() * map.spacing_mm <= COVER_MM {
                    covered[j as usize * map.cols + i as usize] = true;
                }
            }
        }
    }
    s.rms_mm = (sq / s.smooth_points.max(1) as f64).sqrt();
    let (mut cells, mut hit) = (0usize, 0usize);
    for (k, &c) in covered.iter().enumerate() {
        if on_part(k) {
            cells += 1;
            hit += usize::from(c);
        }
    }
    s.coverage = hit as f64 / cells.max(1) as f64;
    s
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

    /// A 10 x 10 mm map of 0.1 mm cells: a 5 mm plate over x >= 5 mm, the belt (0) elsewhere.
    fn plate_map() -> HeightMap {
        let (cols, rows) = (101, 101);
        let z = (0..rows * cols)
            .map(|k| if k % cols >= 50 { 5.0 } else { 0.0 })
            .collect();
        HeightMap {
            origin_mm: [0.0, 0.0],
            spacing_mm: 0.1,
            cols,
            rows,
            z,
        }
    }

    #[test]
    fn heights_are_bilinear_and_the_smooth_mask_leaves_out_the_edge() {
        let m = plate_map();
        assert_eq!(m.at(2.0, 3.0), Some(0.0));
        assert!((m.at(4.95, 3.0).expect("inside") - 2.5).abs() < 1e-9);
        assert_eq!(m.at(-0.1, 3.0), None);
        assert_eq!(m.at(3.0, 10.0), None, "the last row has no cell beyond it");
        let smooth = m.smooth_mask(1.0, 0.25);
        assert!(smooth[50 * 101 + 20] && smooth[50 * 101 + 80]);
        assert!(
            !smooth[50 * 101 + 45] && !smooth[50 * 101 + 55],
            "within 1 mm of the step"
        );
    }

    #[test]
    fn points_are_scored_for_gross_errors_rms_and_coverage() {
        let m = plate_map();
        // Every 0.2 mm of the plate's smooth part, 0.01 mm high, and one point 1 mm off and one outside.
        let mut pts = Vec::new();
        for j in 0..50 {
            for i in 0..50 {
                pts.push([5.0 + 0.1 * f64::from(i), 0.2 * f64::from(j), 5.01]);
            }
        }
        pts.push([7.0, 5.0, 6.0]);
        pts.push([70.0, 5.0, 6.0]);
        let s = score_heights(&m, &pts);
        assert_eq!((s.points, s.outside, s.gross), (2501, 1, 1));
        assert!((s.rms_mm - 0.01).abs() < 1e-6, "{s:?}");
        assert!(s.coverage > 0.9, "{s:?}");
        // Half the plate left out: half the smooth cells covered.
        let half: Vec<[f64; 3]> = pts.iter().copied().filter(|p| p[1] < 5.0).collect();
        let c = score_heights(&m, &half).coverage;
        assert!((0.4..0.6).contains(&c), "{c}");
    }

    #[test]
    fn a_height_map_is_refused_by_field() {
        let dir = std::env::temp_dir().join(format!("stripe3d-hm-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        let json = dir.join("heightmap.json");
        std::fs::write(
            &json,
            r#"{"origin_mm": [0, 0], "spacing_mm": -1, "rows": 4, "cols": 4}"#,
        )
        .expect("write");
        let e = read_height_map(&json)
            .expect_err("negative spacing")
            .to_string();
        assert!(e.contains("spacing_mm"), "{e}");
        std::fs::write(
            &json,
            r#"{"origin_mm": [0], "spacing_mm": 0.1, "rows": 4, "cols": 4}"#,
        )
        .expect("write");
        let e = read_height_map(&json).expect_err("one origin").to_string();
        assert!(e.contains("origin_mm"), "{e}");
        std::fs::write(
            &json,
            r#"{"origin_mm": [0, 0], "spacing_mm": 0.1, "rows": 4, "cols": 4}"#,
        )
        .expect("write");
        let e = read_height_map(&json).expect_err("no tiff").to_string();
        assert!(e.contains("heightmap.tiff"), "{e}");
        let defects = dir.join("defects.json");
        std::fs::write(&defects, r#"[{"kind": "hole", "x_mm": 1}]"#).expect("write");
        let e = read_true_defects(&defects)
            .expect_err("missing fields")
            .to_string();
        assert!(e.contains("defects.json"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
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
