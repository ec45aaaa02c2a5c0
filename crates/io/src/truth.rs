//! Writing the simulator's ground truth: stripe points (CSV), the true height map (float32 TIFF + JSON), the
//! defects put into the scene (JSON).

use crate::images::{height_preview, write_f32_tiff, write_rgb_png};
use crate::{IoError, write_atomic};
use serde::Serialize;
use std::fmt::Write as _;
use std::path::Path;
use stripe3d_sim::heightfield::HeightField;
use stripe3d_sim::{DefectTruth, TruthPoint};

/// Header of `stripes.csv`.
pub const STRIPES_CSV_HEADER: &str = "frame,row,stripe,u,x_mm,y_mm,z_mm,part_x_mm";

/// Appends the truth points of one frame to a CSV text (world x, y, z and the part x).
pub fn append_stripes_csv(out: &mut String, frame: usize, points: &[TruthPoint]) {
    for p in points {
        let _ = writeln!(
            out,
            "{frame},{},{},{:.6},{:.6},{:.6},{:.6},{:.6}",
            p.row, p.stripe, p.u, p.world[0], p.world[1], p.world[2], p.part[0]
        );
    }
}

/// Description of a height-map grid written beside its TIFF.
#[derive(Debug, Clone, Serialize)]
pub struct GridIndex {
    /// x and y of the first sample (column 0, row 0), mm.
    pub origin_mm: [f64; 2],
    /// Sample spacing along x and y, mm.
    pub spacing_mm: [f64; 2],
    /// Samples along x.
    pub width: usize,
    /// Samples along y.
    pub height: usize,
    /// Units of the samples.
    pub units: &'static str,
    /// How samples map to coordinates.
    pub layout: &'static str,
}

/// Writes `heightmap.tiff`, `heightmap.json` and the colour preview `heightmap.png` into `dir`.
pub fn write_height_map(dir: &Path, field: &HeightField) -> Result<GridIndex, IoError> {
    let (nx, ny) = field.size();
    let (x0, y0) = field.origin_mm();
    let g = field.spacing_mm();
    let index = GridIndex {
        origin_mm: [x0, y0],
        spacing_mm: [g, g],
        width: nx,
        height: ny,
        units: "mm",
        layout: if nx > 0 {
            "float32 heights above the belt in part coordinates; column i is x = origin_x + i*spacing_x, \
             row j is y = origin_y + j*spacing_y (row 0 is the smallest y); the preview PNG shows +y up"
        } else {
            "no part: the belt is flat at height 0 everywhere, so no heightmap.tiff is written"
        },
    };
    if nx > 0 {
        write_f32_tiff(&dir.join("heightmap.tiff"), nx, ny, field.heights())?;
    }
    let json = serde_json::to_string_pretty(&index).unwrap_or_default();
    write_atomic(&dir.join("heightmap.json"), json.as_bytes())?;
    if nx > 0 {
        let rgb = height_preview(nx, ny, field.heights(), 0.0, field.max_height_mm());
        write_rgb_png(&dir.join("heightmap.png"), nx, ny, &rgb)?;
    }
    Ok(index)
}

/// Writes `defects.json`.
pub fn write_defects(dir: &Path, defects: &[DefectTruth]) -> Result<(), IoError> {
    let json = serde_json::to_string_pretty(defects).unwrap_or_default();
    write_atomic(&dir.join("defects.json"), json.as_bytes())
}
