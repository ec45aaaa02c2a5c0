//! Reading a range image back (`range.json` + `range.tiff`, as `stripe3d scan` writes them), and writing an
//! inspection: `report.json` and the pictures a person looks at instead of reading — the range image colour-mapped
//! with every defect outlined and numbered, and the deviation map (blue below the reference, red above).

use crate::IoError;
use crate::files::{read_text, write_atomic};
use crate::images::{colormap, write_rgb_png};
use std::path::{Path, PathBuf};
use stripe3d_core::accumulate::RangeImage;
use stripe3d_core::detect::{Defect, DefectKind};

/// Largest range image read, cells.
pub const MAX_RANGE_CELLS: usize = 64 << 20;

/// Reads a range image: `path` is a `range.json` or a folder holding one (the output folder of `stripe3d scan`).
pub fn read_range(path: &Path) -> Result<RangeImage, IoError> {
    let json_path = range_json_path(path);
    let text = read_text(&json_path)?;
    range_from_json(&json_path, &text)
}

/// The `range.json` that `path` names: the file itself, or the one in the folder.
fn range_json_path(path: &Path) -> PathBuf {
    if path.is_dir() {
        path.join("range.json")
    } else {
        path.to_path_buf()
    }
}

/// The `range.json` that `path` names, parsed; `None` when it cannot be read or parsed (the fields read from it
/// are optional extras beside the range image, which [`read_range`] reports errors for).
fn range_doc(path: &Path) -> Option<serde_json::Value> {
    serde_json::from_str(&read_text(&range_json_path(path)).ok()?).ok()
}

/// The warnings the scan a range image came from recorded in its `range.json` (`warnings`, see `stripe3d scan`):
/// empty when there are none or the file does not say. `path` as for [`read_range`].
pub fn range_warnings(path: &Path) -> Vec<String> {
    let Some(doc) = range_doc(path) else {
        return Vec::new();
    };
    doc.get("warnings")
        .and_then(serde_json::Value::as_array)
        .map(|a| {
            a.iter()
                .filter_map(|w| w.as_str().map(str::to_string))
                .collect()
        })
        .unwrap_or_default()
}

/// The conveyor travel between frames of the scan a range image came from, mm, as its `range.json` records it
/// (`frame_step_mm`, or the travel over the frames for files written before that field): `None` when the file does
/// not say (a range image from elsewhere). `path` as for [`read_range`].
pub fn range_travel_step(path: &Path) -> Option<f64> {
    let doc = range_doc(path)?;
    let step = doc
        .get("frame_step_mm")
        .and_then(serde_json::Value::as_f64)
        .or_else(|| {
            let t = doc.get("travel_mm")?.as_array()?;
            let frames = doc.get("frames")?.as_u64()?;
            let (a, b) = (t.first()?.as_f64()?, t.get(1)?.as_f64()?);
            (frames >= 2).then(|| (b - a) / (frames - 1) as f64)
        })?;
    (step.is_finite() && step > 0.0).then_some(step)
}

fn invalid(path: &Path, field: &str, message: impl Into<String>) -> IoError {
    IoError::Invalid {
        path: path.to_path_buf(),
        line: None,
        field: field.into(),
        message: message.into(),
    }
}

/// Parses a `range.json` (its TIFF is read from beside `json_path`).
pub fn range_from_json(json_path: &Path, text: &str) -> Result<RangeImage, IoError> {
    let doc: serde_json::Value = serde_json::from_str(text).map_err(|e| IoError::Syntax {
        path: json_path.to_path_buf(),
        line: e.line(),
        column: e.column(),
        message: format!("{e} (is this a range.json written by `stripe3d scan`?)"),
    })?;
    let size = |field: &str| -> Result<usize, IoError> {
        doc.get(field)
            .and_then(serde_json::Value::as_u64)
            .filter(|&v| v > 0)
            .map(|v| v as usize)
            .ok_or_else(|| invalid(json_path, field, "must be a positive whole number of cells"))
    };
    let pair = |field: &str, positive: bool| -> Result<[f64; 2], IoError> {
        let v = doc
            .get(field)
            .and_then(serde_json::Value::as_array)
            .filter(|a| a.len() == 2)
            .ok_or_else(|| invalid(json_path, field, "must be a list of two numbers [x, y]"))?;
        let mut out = [0.0; 2];
        for (o, x) in out.iter_mut().zip(v) {
            *o = x
                .as_f64()
                .filter(|x| x.is_finite() && (!positive || *x > 0.0))
                .ok_or_else(|| {
                    invalid(
                        json_path,
                        field,
                        if positive {
                            "must hold two positive finite numbers (mm)"
                        } else {
                            "must hold two finite numbers (mm)"
                        },
                    )
                })?;
        }
        Ok(out)
    };
    let (width, height) = (size("width")?, size("height")?);
    if width.saturating_mul(height) > MAX_RANGE_CELLS {
        return Err(invalid(
            json_path,
            "width",
            format!("{width}x{height} cells exceed the limit of {MAX_RANGE_CELLS}"),
        ));
    }
    let origin_mm = pair("origin_mm", false)?;
    let spacing_mm = pair("spacing_mm", true)?;
    let dir = json_path.parent().unwrap_or(Path::new("."));
    let layer = |field: &str, value: Option<&serde_json::Value>| -> Result<PathBuf, IoError> {
        value
            .and_then(serde_json::Value::as_str)
            .filter(|f| !f.is_empty() && !f.contains(['/', '\\']))
            .map(|f| dir.join(f))
            .ok_or_else(|| {
                invalid(
                    json_path,
                    field,
                    "must name the TIFF beside the JSON (e.g. \"range.tiff\")",
                )
            })
    };
    let z = read_layer(
        &layer("file", doc.get("file"))?,
        json_path,
        width,
        height,
        "heights in mm",
    )?;
    // The intensity image, when the JSON names one (`stripe3d scan` writes it; a range image from elsewhere may not
    // have one).
    let intensity = match doc.get("intensity") {
        None | Some(serde_json::Value::Null) => None,
        Some(v) => Some(read_layer(
            &layer("intensity.file", v.get("file"))?,
            json_path,
            width,
            height,
            "grey levels",
        )?),
    };
    Ok(RangeImage {
        origin_mm,
        spacing_mm,
        width,
        height,
        z,
        intensity,
    })
}

/// One float32 layer of a range image (`width` x `height`, finite values and NaN), as the JSON at `json_path`
/// describes it.
pub(crate) fn read_layer(
    tiff_path: &Path,
    json_path: &Path,
    width: usize,
    height: usize,
    what: &str,
) -> Result<Vec<f32>, IoError> {
    let bytes = std::fs::read(tiff_path).map_err(|source| IoError::Read {
        path: tiff_path.to_path_buf(),
        source,
    })?;
    let bad = |m: String| IoError::Image {
        path: tiff_path.to_path_buf(),
        message: m,
    };
    let v = crate::error::decode_guarded(tiff_path, || {
        let mut dec = tiff::decoder::Decoder::new(std::io::Cursor::new(bytes))
            .map_err(|e| bad(format!("not a TIFF: {e}")))?;
        let (tw, th) = dec
            .dimensions()
            .map_err(|e| bad(format!("unreadable size: {e}")))?;
        if (tw as usize, th as usize) != (width, height) {
            return Err(bad(format!(
                "{tw}x{th} cells but {} says {width}x{height}",
                json_path.display()
            )));
        }
        match dec
            .read_image()
            .map_err(|e| bad(format!("cannot decode: {e}")))?
        {
            tiff::decoder::DecodingResult::F32(v) => Ok(v),
            _ => Err(bad(format!("must be one channel of float32 {what}"))),
        }
    })?;
    if v.len() != width * height {
        return Err(bad(format!(
            "{} samples for {width}x{height} cells: one float32 channel is expected",
            v.len()
        )));
    }
    if v.iter().any(|x| x.is_infinite()) {
        return Err(bad(format!(
            "holds infinite {what} (only finite values and NaN are allowed)"
        )));
    }
    Ok(v)
}

/// `report.json`'s format name.
pub const REPORT_FORMAT: &str = "stripe3d-report";
/// `report.json`'s schema version.
pub const REPORT_VERSION: u32 = 1;

/// `report.json`: what `stripe3d inspect` concluded about one part. [`write_report`] writes every object's keys in
/// alphabetical order; the fields of a product inspection are left out without one. Other tools read these names:
/// add fields, never rename them.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Report {
    /// The defects, numbered from 1.
    pub defects: Vec<ReportDefect>,
    /// The smallest defects this scan could show (absent when inspection failed).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub detectable: Option<ReportDetectable>,
    /// With a product: the causes the knowledge base ranks for the part.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub diagnosis: Option<Vec<stripe3d_kb::reason::CauseCertainty>>,
    /// With a product: its designed features and what the scan showed of them.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub features: Option<Vec<stripe3d_kb::reason::FeatureCheck>>,
    /// [`REPORT_FORMAT`].
    pub format: &'static str,
    /// The program and its version.
    pub generator: String,
    /// What was inspected (a scan folder or frames).
    pub input: String,
    /// With a product: the knowledge base used.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub knowledge_base: Option<ReportKnowledgeBase>,
    /// The pictures written beside the report.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pictures: Option<ReportPictures>,
    /// With a product: its name.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub product: Option<String>,
    /// With a product: where the product's frame lies in the scan, mm.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub product_frame_origin_mm: Option<[f64; 2]>,
    /// The range image's grid.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub range: Option<ReportRange>,
    /// The reference surface the deviations are measured from.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reference: Option<ReportReference>,
    /// `inspected`, or `error`.
    pub status: &'static str,
    /// The part's surface as measured.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub surface: Option<ReportSurface>,
    /// With a product: the reasoning, first line the verdict's reason.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub trace: Option<Vec<String>>,
    /// Areas of the part the scan did not measure.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub unmeasured: Option<Vec<ReportUnmeasured>>,
    /// `accept`, `rework`, `reject`, `incomplete`, or `not-inspected`.
    pub verdict: String,
    /// Why.
    pub verdict_reason: String,
    /// [`REPORT_VERSION`].
    pub version: u32,
    /// What makes the result doubtful.
    pub warnings: Vec<String>,
}

/// One defect of [`Report::defects`].
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ReportDefect {
    /// Footprint, mm².
    pub area_mm2: f64,
    /// Bounding box (x0, y0, x1, y1), mm.
    pub bbox_mm: [f64; 4],
    /// Whether a hole's bottom was seen.
    pub bottom_seen: bool,
    /// With a product: the causes ranked for it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub causes: Option<Vec<stripe3d_kb::reason::CauseCertainty>>,
    /// The classification's certainty.
    pub confidence: f64,
    /// With a product: `accept`, `rework` or `reject` for this defect (`accept` for a designed feature).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub decision: Option<String>,
    /// Depth (or height), mm.
    pub depth_mm: f64,
    /// With a product: the designed feature this is.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub designed: Option<String>,
    /// What the classification weighed.
    pub evidence: ReportEvidence,
    /// Number, from 1.
    pub id: usize,
    /// Its kind.
    pub kind: &'static str,
    /// With a product: its position in the product's frame, mm.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub product_xy_mm: Option<[f64; 2]>,
    /// With a product: the rules that decided.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reasons: Option<Vec<String>>,
    /// Volume, mm³.
    pub volume_mm3: f64,
    /// Centre, mm.
    pub x_mm: f64,
    /// Centre, mm.
    pub y_mm: f64,
    /// With a product: the zone it lies in (`null` outside every zone).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub zone: Option<Option<String>>,
}

/// A defect's evidence ([`stripe3d_core::detect::Evidence`]).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ReportEvidence {
    /// Cells.
    pub cells: usize,
    /// Largest |mean curvature|, 1/mm.
    pub curvature_per_mm: f64,
    /// Direction uniformity.
    pub direction: f64,
    /// Notch depth into the outline, mm.
    pub edge_notch_mm: f64,
    /// Elongation.
    pub elongation: f64,
    /// Gap size, mm.
    pub gap_mm: f64,
    /// Height similarity across the gap, mm.
    pub height_similarity_mm: f64,
}

impl ReportDefect {
    /// Defect `n` (from 0) of an inspection, without the product's judgement.
    pub fn of(n: usize, d: &Defect) -> Self {
        let e = &d.evidence;
        Self {
            area_mm2: d.area_mm2,
            bbox_mm: d.bbox_mm,
            bottom_seen: d.bottom_seen,
            causes: None,
            confidence: d.confidence,
            decision: None,
            depth_mm: d.depth_mm,
            designed: None,
            evidence: ReportEvidence {
                cells: e.cells,
                curvature_per_mm: e.curvature_per_mm,
                direction: e.direction,
                edge_notch_mm: e.edge_notch_mm,
                elongation: e.elongation,
                gap_mm: e.gap_mm,
                height_similarity_mm: e.height_similarity_mm,
            },
            id: n + 1,
            kind: d.kind.name(),
            product_xy_mm: None,
            reasons: None,
            volume_mm3: d.volume_mm3,
            x_mm: d.centroid_mm[0],
            y_mm: d.centroid_mm[1],
            zone: None,
        }
    }
}

/// [`Report::detectable`].
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ReportDetectable {
    /// The detection threshold in units of the smoothed noise.
    pub noise_sigmas: f64,
    /// Smallest bump, mm.
    pub smallest_bump_mm: f64,
    /// Smallest dent, mm.
    pub smallest_dent_mm: f64,
    /// Smallest hole, mm.
    pub smallest_hole_mm: f64,
    /// The smoothed deviation's noise, mm.
    pub smoothed_noise_mm: f64,
    /// The detection threshold, mm.
    pub threshold_mm: f64,
    /// Whether the noise raised the threshold above the method's.
    pub threshold_raised: bool,
}

/// [`Report::knowledge_base`].
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ReportKnowledgeBase {
    /// Its folder (`null`: the shipped example).
    pub folder: Option<String>,
    /// Its name.
    pub name: String,
    /// Its version.
    pub version: u32,
}

/// [`Report::pictures`].
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ReportPictures {
    /// The defects picture's file.
    pub defects: &'static str,
    /// The deviation picture's file.
    pub deviation: &'static str,
    /// How to read them.
    pub legend: &'static str,
}

impl Default for ReportPictures {
    fn default() -> Self {
        Self {
            defects: "defects.png",
            deviation: "deviation.png",
            legend: "defects.png: heights colour-mapped, grey = not measured; outlines by kind (red bump, blue dent, \
                     magenta hole, cyan scratch, orange edge chip, white anomaly), labelled number + initial. \
                     deviation.png: blue below the reference, red above, full colour at 5 x the detection threshold.",
        }
    }
}

/// [`Report::range`].
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ReportRange {
    /// Rows.
    pub height: usize,
    /// x of column 0 and y of row 0, mm.
    pub origin_mm: [f64; 2],
    /// Cell size, mm.
    pub spacing_mm: [f64; 2],
    /// Columns.
    pub width: usize,
}

/// [`Report::reference`]: a fitted surface or a registered golden scan.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
#[serde(untagged)]
pub enum ReportReference {
    /// A plane or quadratic fitted to the part.
    Fitted {
        /// Centre of the fit's coordinates, mm.
        centre_mm: [f64; 2],
        /// Its coefficients.
        coefficients: [f64; 6],
        /// What they mean.
        coefficients_meaning: &'static str,
        /// Share of the cells the fit kept.
        inlier_share: f64,
        /// `fitted plane` or `fitted quadratic`.
        kind: String,
        /// The fit's robust spread, mm.
        sigma_mm: f64,
    },
    /// A golden scan registered to the part.
    Golden {
        /// Centre of the rotation, mm.
        centre_mm: [f64; 2],
        /// Shift, mm.
        dx_mm: f64,
        /// Shift, mm.
        dy_mm: f64,
        /// Height shift, mm.
        dz_mm: f64,
        /// `golden scan`.
        kind: &'static str,
        /// Mean clipped height difference after registration, mm.
        mean_clipped_difference_mm: f64,
        /// Share of the part on the golden part.
        overlap: f64,
        /// Rotation, rad.
        theta_rad: f64,
    },
}

impl ReportReference {
    /// The report's account of a reference.
    pub fn of(r: &stripe3d_core::characterize::ReferenceInfo) -> Self {
        use stripe3d_core::characterize::ReferenceInfo;
        match r {
            ReferenceInfo::Fitted(f) => Self::Fitted {
                centre_mm: f.centre_mm,
                coefficients: f.coefficients,
                coefficients_meaning: "z = c0 + c1 x' + c2 y' + c3 x'^2 + c4 x'y' + c5 y'^2, x' = (x - centre) / 10 mm",
                inlier_share: f.inlier_share,
                kind: format!("fitted {}", f.shape.name()),
                sigma_mm: f.sigma_mm,
            },
            ReferenceInfo::Golden(g) => Self::Golden {
                centre_mm: g.centre_mm,
                dx_mm: g.dx_mm,
                dy_mm: g.dy_mm,
                dz_mm: g.dz_mm,
                kind: "golden scan",
                mean_clipped_difference_mm: g.mean_difference_mm,
                overlap: g.overlap,
                theta_rad: g.theta_rad,
            },
        }
    }
}

/// [`Report::surface`].
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ReportSurface {
    /// Measured part cells' share of the part's outline.
    pub coverage: f64,
    /// The height noise of the part's surface, mm.
    pub noise_mm: f64,
    /// Area of the part's cells, mm².
    pub part_area_mm2: f64,
    /// The part's bounding box (x0, y0, x1, y1), mm.
    pub part_bbox_mm: [f64; 4],
}

/// One area of [`Report::unmeasured`].
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ReportUnmeasured {
    /// Area, mm².
    pub area_mm2: f64,
    /// Why it was not measured.
    pub reason: String,
    /// Centre, mm.
    pub x_mm: f64,
    /// Centre, mm.
    pub y_mm: f64,
}

impl Report {
    /// The report of an inspection that could not be made: `message` says why.
    pub fn error(message: &str, input: &str) -> Self {
        Self {
            defects: Vec::new(),
            detectable: None,
            diagnosis: None,
            features: None,
            format: REPORT_FORMAT,
            generator: generator(),
            input: input.to_string(),
            knowledge_base: None,
            pictures: None,
            product: None,
            product_frame_origin_mm: None,
            range: None,
            reference: None,
            status: "error",
            surface: None,
            trace: None,
            unmeasured: None,
            verdict: "not-inspected".to_string(),
            verdict_reason: message.to_string(),
            version: REPORT_VERSION,
            warnings: vec![message.to_string()],
        }
    }
}

/// The program and its version, as reports name it.
pub fn generator() -> String {
    format!("stripe3d {}", env!("CARGO_PKG_VERSION"))
}

/// Outline colour of a defect kind.
pub fn kind_colour(kind: DefectKind) -> [u8; 3] {
    match kind {
        DefectKind::Bump => [255, 60, 40],
        DefectKind::Dent => [40, 140, 255],
        DefectKind::Hole => [255, 0, 255],
        DefectKind::Scratch => [0, 255, 255],
        DefectKind::EdgeChip => [255, 160, 0],
        DefectKind::Anomaly => [255, 255, 255],
    }
}

/// 3 x 5 glyphs (rows top to bottom, 3 bits each, high bit left) for labels.
fn glyph(c: char) -> Option<[u8; 5]> {
    Some(match c {
        '0' => [7, 5, 5, 5, 7],
        '1' => [2, 6, 2, 2, 7],
        '2' => [7, 1, 7, 4, 7],
        '3' => [7, 1, 7, 1, 7],
        '4' => [5, 5, 7, 1, 1],
        '5' => [7, 4, 7, 1, 7],
        '6' => [7, 4, 7, 5, 7],
        '7' => [7, 1, 1, 1, 1],
        '8' => [7, 5, 7, 5, 7],
        '9' => [7, 5, 7, 1, 7],
        'B' => [6, 5, 6, 5, 6],
        'D' => [6, 5, 5, 5, 6],
        'H' => [5, 5, 7, 5, 5],
        'S' => [7, 4, 7, 1, 7],
        'C' => [7, 4, 4, 4, 7],
        'A' => [2, 5, 7, 5, 5],
        _ => return None,
    })
}

/// An RGB canvas.
struct Canvas {
    w: usize,
    h: usize,
    rgb: Vec<u8>,
}

impl Canvas {
    fn put(&mut self, x: i64, y: i64, c: [u8; 3]) {
        if x >= 0 && y >= 0 && (x as usize) < self.w && (y as usize) < self.h {
            let k = 3 * (y as usize * self.w + x as usize);
            self.rgb[k..k + 3].copy_from_slice(&c);
        }
    }

    fn text(&mut self, x: i64, y: i64, s: &str, scale: i64, c: [u8; 3]) {
        let mut cx = x;
        for ch in s.chars() {
            if let Some(g) = glyph(ch) {
                for (r, bits) in g.iter().enumerate() {
                    for b in 0..3 {
                        if bits & (4 >> b) != 0 {
                            for dy in 0..scale {
                                for dx in 0..scale {
                                    // A dark shadow keeps labels legible on any colour.
                                    self.put(
                                        cx + b * scale + dx + 1,
                                        y + r as i64 * scale + dy + 1,
                                        [0, 0, 0],
                                    );
                                    self.put(cx + b * scale + dx, y + r as i64 * scale + dy, c);
                                }
                            }
                        }
                    }
                }
            }
            cx += 4 * scale;
        }
    }

    fn rect(&mut self, x0: i64, y0: i64, x1: i64, y1: i64, c: [u8; 3]) {
        for t in 0..2 {
            for x in x0 - t..=x1 + t {
                self.put(x, y0 - t, c);
                self.put(x, y1 + t, c);
            }
            for y in y0 - t..=y1 + t {
                self.put(x0 - t, y, c);
                self.put(x1 + t, y, c);
            }
        }
    }

    fn circle(&mut self, cx: f64, cy: f64, r: f64, c: [u8; 3]) {
        let n = (r * 8.0).ceil().max(24.0) as usize;
        for k in 0..n {
            let a = k as f64 / n as f64 * std::f64::consts::TAU;
            for dr in [0.0, 1.0] {
                self.put(
                    (cx + (r + dr) * a.cos()).round() as i64,
                    (cy + (r + dr) * a.sin()).round() as i64,
                    c,
                );
            }
        }
    }
}

/// Pixels per range cell in the pictures (small range images are enlarged so labels stay legible).
fn picture_scale(range: &RangeImage) -> usize {
    (1600 / range.width.max(range.height).max(1)).clamp(1, 4)
}

/// The range image colour-mapped (heights, +y up, grey where nothing was measured) with every defect outlined in
/// its kind's colour and labelled with its number and initial (B bump, D dent, H hole, S scratch, C edge chip,
/// A anomaly).
pub fn defects_picture(range: &RangeImage, defects: &[Defect]) -> (usize, usize, Vec<u8>) {
    let s = picture_scale(range);
    let (w, h) = (range.width * s, range.height * s);
    let (lo, hi) = range
        .z_range()
        .map_or((0.0, 1.0), |(a, b)| (f64::from(a), f64::from(b)));
    let span = if hi > lo { hi - lo } else { 1.0 };
    let mut c = Canvas {
        w,
        h,
        rgb: vec![0; w * h * 3],
    };
    for y in 0..h {
        for x in 0..w {
            let z = f64::from(range.z[(y / s) * range.width + x / s]);
            let col = if z.is_finite() {
                colormap((z - lo) / span)
            } else {
                [110, 110, 110]
            };
            c.put(x as i64, y as i64, col);
        }
    }
    draw_defects(&mut c, range, defects, s);
    (w, h, c.rgb)
}

fn to_px(range: &RangeImage, s: usize, x: f64, y: f64) -> (f64, f64) {
    (
        ((x - range.origin_mm[0]) / range.spacing_mm[0] + 0.5) * s as f64,
        ((range.origin_mm[1] - y) / range.spacing_mm[1] + 0.5) * s as f64,
    )
}

fn draw_defects(c: &mut Canvas, range: &RangeImage, defects: &[Defect], s: usize) {
    for (n, d) in defects.iter().enumerate() {
        let col = kind_colour(d.kind);
        let (px0, py0) = to_px(range, s, d.bbox_mm[0], d.bbox_mm[3]);
        let (px1, py1) = to_px(range, s, d.bbox_mm[2], d.bbox_mm[1]);
        match d.kind {
            DefectKind::Bump | DefectKind::Dent | DefectKind::Hole => {
                let (cx, cy) = to_px(range, s, d.centroid_mm[0], d.centroid_mm[1]);
                let r = ((px1 - px0).max(py1 - py0) / 2.0).max(4.0) + 2.0;
                c.circle(cx, cy, r, col);
            }
            _ => c.rect(
                px0 as i64 - 2,
                py0 as i64 - 2,
                px1 as i64 + 2,
                py1 as i64 + 2,
                col,
            ),
        }
        let initial = match d.kind {
            DefectKind::Bump => 'B',
            DefectKind::Dent => 'D',
            DefectKind::Hole => 'H',
            DefectKind::Scratch => 'S',
            DefectKind::EdgeChip => 'C',
            DefectKind::Anomaly => 'A',
        };
        let scale = (s as i64).max(2);
        c.text(
            px1 as i64 + 4,
            py0 as i64 - 4,
            &format!("{}{initial}", n + 1),
            scale,
            col,
        );
    }
}

/// The deviation map: blue below the reference, red above, white on it, at ±`full_scale_mm`; grey where there is
/// no deviation (not the part, not measured). Defects outlined as in [`defects_picture`].
pub fn deviation_picture(
    range: &RangeImage,
    deviation_mm: &[f32],
    full_scale_mm: f64,
    defects: &[Defect],
) -> (usize, usize, Vec<u8>) {
    let s = picture_scale(range);
    let (w, h) = (range.width * s, range.height * s);
    let mut c = Canvas {
        w,
        h,
        rgb: vec![0; w * h * 3],
    };
    for y in 0..h {
        for x in 0..w {
            let d = f64::from(deviation_mm[(y / s) * range.width + x / s]);
            let col = if !d.is_finite() {
                [90, 90, 90]
            } else {
                let t = (d / full_scale_mm).clamp(-1.0, 1.0);
                let f = |v: f64| (255.0 * (1.0 - v.abs())).round() as u8;
                if t >= 0.0 {
                    [255, f(t), f(t)]
                } else {
                    [f(t), f(t), 255]
                }
            };
            c.put(x as i64, y as i64, col);
        }
    }
    draw_defects(&mut c, range, defects, s);
    // Dark outlines read better on the white map.
    (w, h, c.rgb)
}

/// Writes a picture made by [`defects_picture`] or [`deviation_picture`].
pub fn write_picture(path: &Path, picture: &(usize, usize, Vec<u8>)) -> Result<(), IoError> {
    write_rgb_png(path, picture.0, picture.1, &picture.2)
}

/// Writes `report.json` (pretty JSON, every object's keys in alphabetical order) into `dir`.
pub fn write_report(dir: &Path, report: &Report) -> Result<(), IoError> {
    let path = dir.join("report.json");
    let text = serde_json::to_value(report)
        .and_then(|v| serde_json::to_string_pretty(&v))
        .map_err(|e| IoError::Write {
            path: path.clone(),
            source: std::io::Error::other(e),
        })?;
    write_atomic(&path, text.as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cloud::write_range;
    use proptest::prelude::*;

    fn sample() -> RangeImage {
        RangeImage {
            origin_mm: [-1.0, 2.0],
            spacing_mm: [0.2, 0.25],
            width: 4,
            height: 3,
            z: vec![
                1.0,
                2.0,
                f32::NAN,
                4.0,
                5.0,
                6.0,
                7.0,
                8.0,
                9.0,
                10.0,
                11.0,
                12.0,
            ],
            intensity: None,
        }
    }

    #[test]
    fn a_written_range_reads_back() {
        let dir = tempfile::tempdir().expect("tmp");
        let r = sample();
        write_range(dir.path(), &r, serde_json::json!({})).expect("write");
        let back = read_range(dir.path()).expect("read");
        assert_eq!(back.origin_mm, r.origin_mm);
        assert_eq!(back.spacing_mm, r.spacing_mm);
        assert_eq!((back.width, back.height), (4, 3));
        assert!(back.z[2].is_nan() && back.z[11] == 12.0);
    }

    #[test]
    fn the_intensity_image_is_written_and_read_back_with_the_heights() {
        let dir = tempfile::tempdir().expect("tmp");
        let mut r = sample();
        r.intensity = Some(
            r.z.iter()
                .map(|z| if z.is_finite() { 10.0 * z } else { f32::NAN })
                .collect(),
        );
        write_range(dir.path(), &r, serde_json::json!({})).expect("write");
        let back = read_range(dir.path()).expect("read");
        let i = back.intensity.expect("intensities");
        assert!(i[2].is_nan() && i[0] == 10.0 && i[11] == 120.0);
        // The 8-bit preview: 0 where nothing was measured, the brightest cell at 255.
        let png = image::open(dir.path().join("intensity.png"))
            .expect("png")
            .to_luma8();
        assert_eq!(png.dimensions(), (4, 3));
        assert_eq!((png.as_raw()[2], png.as_raw()[11]), (0, 255));
        // A range image without intensities writes none, and one whose JSON names none reads as none.
        let plain = tempfile::tempdir().expect("tmp");
        write_range(plain.path(), &sample(), serde_json::json!({})).expect("write");
        assert!(!plain.path().join("intensity.tiff").exists());
        assert_eq!(read_range(plain.path()).expect("read").intensity, None);
        // A named intensity file that is missing, of another size or not a TIFF is refused by name.
        let p = dir.path().join("range.json");
        let good = std::fs::read_to_string(&p).expect("json");
        std::fs::write(dir.path().join("other.tiff"), b"not a tiff").expect("write");
        let cases = [
            (
                good.replace("\"file\": \"intensity.tiff\"", "\"file\": \"gone.tiff\""),
                "gone.tiff",
            ),
            (
                good.replace("\"file\": \"intensity.tiff\"", "\"file\": \"other.tiff\""),
                "other.tiff",
            ),
            (
                good.replace("\"file\": \"intensity.tiff\"", "\"file\": \"range.png\""),
                "range.png",
            ),
            (
                good.replace("\"file\": \"intensity.tiff\"", "\"file\": 3"),
                "intensity.file",
            ),
        ];
        for (text, needle) in cases {
            assert_ne!(text, good, "{needle}: the case must change the file");
            let e = range_from_json(&p, &text).expect_err(needle);
            assert!(e.to_string().contains(needle), "{needle}: {e}");
        }
    }

    #[test]
    fn the_travel_step_comes_from_range_json() {
        let dir = tempfile::tempdir().expect("tmp");
        write_range(
            dir.path(),
            &sample(),
            serde_json::json!({"frame_step_mm": 0.5}),
        )
        .expect("write");
        assert_eq!(range_travel_step(dir.path()), Some(0.5));
        // Files written before the field: from the travel over the frames.
        write_range(
            dir.path(),
            &sample(),
            serde_json::json!({"frames": 22, "travel_mm": [0.0, 10.5]}),
        )
        .expect("write");
        assert_eq!(range_travel_step(&dir.path().join("range.json")), Some(0.5));
        // A range image from elsewhere, one frame, or nonsense: unknown.
        for meta in [
            serde_json::json!({}),
            serde_json::json!({"frames": 1, "travel_mm": [0.0, 0.0]}),
            serde_json::json!({"frame_step_mm": -1.0}),
        ] {
            write_range(dir.path(), &sample(), meta).expect("write");
            assert_eq!(range_travel_step(dir.path()), None);
        }
        assert_eq!(range_travel_step(&dir.path().join("missing.json")), None);
    }

    #[test]
    fn broken_range_files_name_the_field() {
        let dir = tempfile::tempdir().expect("tmp");
        write_range(dir.path(), &sample(), serde_json::json!({})).expect("write");
        let p = dir.path().join("range.json");
        let good = std::fs::read_to_string(&p).expect("json");
        let cases = [
            (good.replace("\"width\": 4", "\"width\": 5"), "range.tiff"),
            (good.replace("\"width\": 4", "\"width\": -4"), "width"),
            (
                good.replace("\"file\": \"range.tiff\"", "\"file\": \"../x.tiff\""),
                "file",
            ),
            ("{".to_string(), "range.json:1"),
        ];
        for (text, needle) in cases {
            let e = range_from_json(&p, &text).expect_err(needle);
            assert!(e.to_string().contains(needle), "{needle}: {e}");
        }
        let sp = good.replacen("0.2,", "0.0,", 1);
        let e = range_from_json(&p, &sp).expect_err("zero spacing");
        assert!(e.to_string().contains("spacing_mm"), "{e}");
    }

    #[test]
    fn an_error_report_names_only_what_it_knows_in_alphabetical_order() {
        let dir = tempfile::tempdir().expect("tmp");
        write_report(dir.path(), &Report::error("no part", "scan/")).expect("write");
        let text = std::fs::read_to_string(dir.path().join("report.json")).expect("report");
        let v: serde_json::Value = serde_json::from_str(&text).expect("json");
        let keys: Vec<&str> = v
            .as_object()
            .expect("object")
            .keys()
            .map(String::as_str)
            .collect();
        assert_eq!(
            keys,
            [
                "defects",
                "format",
                "generator",
                "input",
                "status",
                "verdict",
                "verdict_reason",
                "version",
                "warnings"
            ]
        );
        assert_eq!(v["verdict"], "not-inspected");
        assert_eq!(v["warnings"][0], "no part");
        let at = |k: &str| text.find(&format!("\"{k}\"")).expect("key");
        assert!(at("defects") < at("format") && at("verdict_reason") < at("warnings"));
    }

    /// Overwrites bytes of the file at `path` (positions modulo its length) and cuts it short.
    fn damage(path: &Path, flips: &[(usize, u8)], cut: Option<usize>) {
        let mut bytes = std::fs::read(path).expect("file");
        for &(pos, byte) in flips {
            let k = pos % bytes.len();
            bytes[k] = byte;
        }
        if let Some(c) = cut {
            bytes.truncate(c % (bytes.len() + 1));
        }
        std::fs::write(path, &bytes).expect("write");
    }

    proptest! {
        #[test]
        fn arbitrary_json_never_panics(text in ".{0,300}") {
            let _ = range_from_json(Path::new("/nonexistent/range.json"), &text);
        }

        #[test]
        fn mutated_range_json_never_panics(cut in 0usize..400, byte in any::<u8>()) {
            let doc = serde_json::json!({"file": "range.tiff", "width": 4, "height": 3, "origin_mm": [0.0, 0.0],
                "spacing_mm": [0.2, 0.2]}).to_string();
            let mut b = doc.into_bytes();
            let k = cut % b.len();
            b[k] = byte;
            let _ = range_from_json(Path::new("/nonexistent/range.json"), &String::from_utf8_lossy(&b));
        }

        #[test]
        fn damaged_range_tiffs_are_refused_by_name_or_read(
            flips in proptest::collection::vec((0usize..4096, any::<u8>()), 1..4),
            cut in proptest::option::of(0usize..4096),
        ) {
            let dir = tempfile::tempdir().expect("tmp");
            write_range(dir.path(), &sample(), serde_json::json!({})).expect("write");
            damage(&dir.path().join("range.tiff"), &flips, cut);
            match read_range(dir.path()) {
                Ok(r) => prop_assert!(r.z.len() == 12 && r.z.iter().all(|z| !z.is_infinite())),
                Err(e) => prop_assert!(e.to_string().contains("range."), "{}", e),
            }
        }

        #[test]
        fn damaged_intensity_tiffs_are_refused_by_name_or_read(
            flips in proptest::collection::vec((0usize..4096, any::<u8>()), 1..4),
            cut in proptest::option::of(0usize..4096),
        ) {
            let dir = tempfile::tempdir().expect("tmp");
            let mut r = sample();
            r.intensity = Some(r.z.iter().map(|z| 10.0 * z).collect());
            write_range(dir.path(), &r, serde_json::json!({})).expect("write");
            damage(&dir.path().join("intensity.tiff"), &flips, cut);
            match read_range(dir.path()) {
                Ok(r) => prop_assert!(r.intensity.is_some_and(|i| i.len() == 12
                    && i.iter().all(|v| !v.is_infinite()))),
                Err(e) => prop_assert!(e.to_string().contains("intensity.tiff"), "{}", e),
            }
        }
    }
}
