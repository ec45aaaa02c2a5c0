//! `stripe3d bench validation DIR`: a validation set laid out as `../shared/validation/`, scored exactly as its
//! README says. Extraction: a true centre is found by the nearest point of its row within 0.5 px, each point used
//! once; a point farther than 1.5 px from every true centre of its row is false. Calibration: the sensor is
//! calibrated from `calib/plane_HH.HH.png` (HH the plate's height, mm). Scans: every scan of `scans/` is scanned
//! with that calibration and its points compared with the true height map (gross errors, RMS on smooth parts of
//! the part, coverage; see [`stripe3d_io::validation::score_heights`]); a scan whose part is flat apart from its
//! listed defects is inspected against a fitted plane and its reported defects matched with the true ones.

use crate::extract::run_frame;
use crate::scan::{
    calibrate_plates, coding_with_range, default_grid, frame_list, scan_frames, travel_step,
    travels,
};
use anyhow::{Context, Result, bail};
use std::path::{Path, PathBuf};
use stripe3d_core::Sensor;
use stripe3d_core::accumulate::ModelKind;
use stripe3d_core::calibrate::Calibration;
use stripe3d_core::characterize::{CharacterizeParams, ReferenceShape, ReferenceSource};
use stripe3d_core::code::{CodingParams, CodingStats};
use stripe3d_core::detect::{DetectParams, SurfaceRules, inspect};
use stripe3d_core::extract::{ExtractParams, Extraction, Extractor};
use stripe3d_io::images::{Laser, read_frame_native};
use stripe3d_io::read_sensor;
use stripe3d_io::validation::{
    HeightMap, HeightScore, PART_MM, SMOOTH_RADIUS_MM, SMOOTH_STEP_MM, TrueDefect, extract_cases,
    read_height_map, read_true_centres, read_true_defects, scan_cases, score_profiles,
};
use stripe3d_sim::evaluate::RowScore;

/// Largest frame read, pixels.
const MAX_PIXELS: usize = 64 << 20;

/// One frame's figures.
#[derive(Debug, Clone)]
pub struct FrameFigures {
    /// The frame's name.
    pub name: String,
    /// Its score.
    pub score: RowScore,
}

/// Scores extraction with `params` on every frame of `dir/extract/`.
pub fn score_extraction(dir: &Path, params: &ExtractParams) -> Result<Vec<FrameFigures>> {
    let folder = dir.join("extract");
    if !folder.is_dir() {
        bail!(
            "{}: no extract/ folder (a validation set holds extract/, calib/ and scans/, as ../shared/validation/)",
            dir.display()
        );
    }
    let cases = extract_cases(&folder)?;
    if cases.is_empty() {
        bail!(
            "{}: no NAME.png with a NAME.truth.csv beside it",
            folder.display()
        );
    }
    let mut ex = Extractor::new(params.clone())?;
    let mut out = Extraction::default();
    let mut figures = Vec::new();
    for c in &cases {
        let frame = read_frame_native(&c.image, MAX_PIXELS)?;
        let truth: Vec<(u32, f64)> = read_true_centres(&c.truth)?
            .iter()
            .map(|t| (t.row, t.x))
            .collect();
        run_frame(&mut ex, &frame, &mut out);
        let reported: Vec<(u32, f64)> = out.points.iter().map(|p| (p.row, p.x)).collect();
        figures.push(FrameFigures {
            name: c.name.clone(),
            score: RowScore::of(&truth, &reported),
        });
    }
    Ok(figures)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    match v.len() {
        0 => f64::NAN,
        n if n % 2 == 1 => v[n / 2],
        n => 0.5 * (v[n / 2 - 1] + v[n / 2]),
    }
}

/// The sensor of `dir/calib/` calibrated from its plates (`plane_HH.HH.png`, HH the height in mm).
pub fn calibrate_set(dir: &Path, params: &ExtractParams) -> Result<(Sensor, Calibration)> {
    let folder = dir.join("calib");
    let sensor = read_sensor(&folder.join("sensor.toml"))?;
    let mut planes: Vec<(f64, PathBuf)> = Vec::new();
    for p in stripe3d_io::files::read_dir(&folder)? {
        let name = p.file_name().and_then(|n| n.to_str()).unwrap_or_default();
        let Some(h) = name
            .strip_prefix("plane_")
            .and_then(|n| n.strip_suffix(".png"))
        else {
            continue;
        };
        let h: f64 = h.parse().with_context(|| {
            format!(
                "{}: the name must give the plate's height in mm (plane_HH.HH.png)",
                p.display()
            )
        })?;
        planes.push((h, p.clone()));
    }
    if planes.is_empty() {
        bail!("{}: no plane_HH.HH.png plates", folder.display());
    }
    let cal = calibrate_plates(&sensor, &planes, params.method.name(), Laser::Auto)
        .with_context(|| format!("calibrating from {}", folder.display()))?;
    Ok((sensor, cal))
}

/// A scan's defects matched with the true ones (README: a reported centre within max(2 mm, the true radius) of a
/// true centre, each true defect used once).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DefectMatch {
    /// True defects.
    pub truth: usize,
    /// Reported defects.
    pub reported: usize,
    /// Reported defects matched with a true one.
    pub matched: usize,
    /// Of the matched, those of the true kind.
    pub right_kind: usize,
}

/// One scan's figures.
#[derive(Debug, Clone)]
pub struct ScanFigures {
    /// The scan's name.
    pub name: String,
    /// Frames.
    pub frames: usize,
    /// The points' heights against the truth.
    pub heights: HeightScore,
    /// Coding counts.
    pub coding: CodingStats,
    /// Defects, for a scan whose part is flat apart from its listed defects.
    pub defects: Option<DefectMatch>,
    /// Seconds for extraction, coding and triangulation.
    pub seconds: f64,
}

/// Whether the true part of `map` is flat (within the scoring's smoothness step) away from its listed defects and
/// from its edges.
fn flat_apart_from(map: &HeightMap, defects: &[TrueDefect]) -> bool {
    let smooth = map.smooth_mask(SMOOTH_RADIUS_MM, SMOOTH_STEP_MM);
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for j in 0..map.rows {
        for i in 0..map.cols {
            let z = map.cell(i, j);
            if !smooth[j * map.cols + i] || z <= PART_MM {
                continue;
            }
            let (x, y) = (
                map.origin_mm[0] + i as f64 * map.spacing_mm,
                map.origin_mm[1] + j as f64 * map.spacing_mm,
            );
            let near = defects
                .iter()
                .any(|d| (x - d.x_mm).hypot(y - d.y_mm) <= d.radius_mm + 1.0);
            if !near {
                lo = lo.min(z);
                hi = hi.max(z);
            }
        }
    }
    hi - lo < SMOOTH_STEP_MM
}

/// Matches reported defects (kind name, centre) with the true ones, greedily by distance.
pub fn match_defects(truth: &[TrueDefect], reported: &[(&str, [f64; 2])]) -> DefectMatch {
    let mut pairs: Vec<(f64, usize, usize)> = Vec::new();
    for (t, d) in truth.iter().enumerate() {
        for (r, (_, c)) in reported.iter().enumerate() {
            let dist = (c[0] - d.x_mm).hypot(c[1] - d.y_mm);
            if dist <= d.radius_mm.max(2.0) {
                pairs.push((dist, t, r));
            }
        }
    }
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (mut used_t, mut used_r) = (vec![false; truth.len()], vec![false; reported.len()]);
    let mut m = DefectMatch {
        truth: truth.len(),
        reported: reported.len(),
        ..DefectMatch::default()
    };
    for (_, t, r) in pairs {
        if used_t[t] || used_r[r] {
            continue;
        }
        used_t[t] = true;
        used_r[r] = true;
        m.matched += 1;
        m.right_kind += usize::from(reported[r].0 == truth[t].kind);
    }
    m
}

/// Scans and scores every scan of `dir/scans/` with calibration `cal`.
pub fn score_scans(
    dir: &Path,
    sensor: &Sensor,
    cal: &Calibration,
    params: &ExtractParams,
    spacetime: bool,
) -> Result<Vec<ScanFigures>> {
    let folder = dir.join("scans");
    let cases = scan_cases(&folder)?;
    let mut out = Vec::new();
    for c in &cases {
        let frames = frame_list(&[c.frames()])?;
        let scan_sensor = read_sensor(&c.sensor())?;
        if scan_sensor.camera != sensor.camera {
            bail!(
                "{}: its camera differs from calib/sensor.toml's; the set's scans must share the calibrated camera",
                c.sensor().display()
            );
        }
        let travel = travels(&scan_sensor, None, frames.len())?;
        let coding = coding_with_range(CodingParams::default(), cal.coding_range_mm());
        let res = scan_frames(
            &scan_sensor,
            cal,
            &frames,
            &travel,
            params.clone(),
            ModelKind::Full,
            coding,
            default_grid(&scan_sensor),
            true,
            spacetime,
            Laser::Auto,
        )
        .with_context(|| format!("scanning {}", c.dir.display()))?;
        let map = read_height_map(&c.dir.join("heightmap.json"))?;
        let heights = score_profiles(&map, &res.profiles);
        let truth = read_true_defects(&c.dir.join("defects.json"))?;
        let defects = if flat_apart_from(&map, &truth) {
            let mut rules = SurfaceRules::shipped()?;
            let detect = DetectParams {
                travel_step_mm: travel_step(&travel),
                ..DetectParams::default()
            };
            let found = inspect(
                &res.range,
                ReferenceSource::Fit(ReferenceShape::Plane),
                &CharacterizeParams::default(),
                &mut rules,
                &detect,
            )
            .with_context(|| format!("inspecting {}", c.dir.display()))?;
            let reported: Vec<(&str, [f64; 2])> = found
                .detection
                .defects
                .iter()
                .map(|d| (d.kind.name(), d.centroid_mm))
                .collect();
            Some(match_defects(&truth, &reported))
        } else {
            None
        };
        out.push(ScanFigures {
            name: c.name.clone(),
            frames: frames.len(),
            heights,
            coding: res.coding,
            defects,
            seconds: res.seconds,
        });
    }
    Ok(out)
}

/// Runs `stripe3d bench validation`.
pub fn bench_validation(dir: &Path, params: &ExtractParams, spacetime: bool) -> Result<()> {
    let figures = score_extraction(dir, params)
        .with_context(|| format!("validation set {}", dir.display()))?;
    say!(
        "extraction ({}), scored as the validation README says:",
        params.method.name()
    );
    say!("| frame | true centres | recall within 0.5 px | false | RMS px |");
    say!("|---|---:|---:|---:|---:|");
    for f in &figures {
        say!(
            "| {} | {} | {:.4} | {:.4} | {:.3} |",
            f.name,
            f.score.truth,
            f.score.recall(),
            f.score.false_rate(),
            f.score.rms()
        );
    }
    let recall = median(figures.iter().map(|f| f.score.recall()).collect());
    let false_rate = median(figures.iter().map(|f| f.score.false_rate()).collect());
    let rms = median(figures.iter().map(|f| f.score.rms()).collect());
    let worst = figures
        .iter()
        .map(|f| f.score.recall())
        .fold(f64::INFINITY, f64::min);
    let extraction_summary = format!(
        "extraction over {} frames: median recall {recall:.4} (worst {worst:.4}), median false {false_rate:.4}, \
         median RMS {rms:.3} px",
        figures.len()
    );
    if !dir.join("calib").is_dir() {
        say!("no calib/ folder: calibration and scans not scored");
        say!("summary: {extraction_summary}");
        return Ok(());
    }
    let (sensor, cal) = calibrate_set(dir, params)?;
    let full_rms = cal
        .stripes
        .iter()
        .map(|s| s.full_rms_mm)
        .fold(0.0, f64::max);
    let full_max = cal
        .stripes
        .iter()
        .map(|s| s.full_max_mm)
        .fold(0.0, f64::max);
    say!(
        "calibration from {} plates at {:?} mm: {} stripes, height residual RMS at most {full_rms:.4} mm (largest \
         {full_max:.4} mm)",
        cal.heights_mm.len(),
        cal.heights_mm,
        cal.stripes.len()
    );
    if !dir.join("scans").is_dir() {
        say!("no scans/ folder: scans not scored");
        say!("summary: {extraction_summary}; calibration RMS at most {full_rms:.4} mm");
        return Ok(());
    }
    let scans = score_scans(dir, &sensor, &cal, params, spacetime)?;
    say!(
        "scans, scored as the validation README says (gross: more than 0.5 mm off; RMS on smooth parts of the part):"
    );
    say!(
        "| scan | frames | points | gross errors | RMS mm | coverage | dropped in coding | defects: true / reported / matched (right kind) | s |"
    );
    say!("|---|---:|---:|---:|---:|---:|---:|---|---:|");
    for f in &scans {
        let h = &f.heights;
        let dropped = f.coding.points - f.coding.coded;
        let defects = match f.defects {
            Some(d) => format!(
                "{} / {} / {} ({})",
                d.truth, d.reported, d.matched, d.right_kind
            ),
            None => "designed shapes: not inspected".to_string(),
        };
        say!(
            "| {} | {} | {} | {:.2}% | {:.4} | {:.3} | {:.1}% | {} | {:.2} |",
            f.name,
            f.frames,
            h.points,
            100.0 * h.gross_rate(),
            h.rms_mm,
            h.coverage,
            100.0 * dropped as f64 / f.coding.points.max(1) as f64,
            defects,
            f.seconds
        );
    }
    let worst_gross = scans
        .iter()
        .map(|f| f.heights.gross_rate())
        .fold(0.0, f64::max);
    let worst_rms = scans.iter().map(|f| f.heights.rms_mm).fold(0.0, f64::max);
    let worst_cover = scans
        .iter()
        .map(|f| f.heights.coverage)
        .fold(f64::INFINITY, f64::min);
    let (matched, truth, reported) = scans
        .iter()
        .filter_map(|f| f.defects)
        .fold((0, 0, 0), |a, d| {
            (a.0 + d.matched, a.1 + d.truth, a.2 + d.reported)
        });
    say!(
        "summary: {extraction_summary}; calibration RMS at most {full_rms:.4} mm; scans over {}: gross errors at most \
         {:.2}%, RMS at most {worst_rms:.4} mm, coverage at least {worst_cover:.3}, defects {matched} of {truth} \
         found with {reported} reported",
        scans.len(),
        100.0 * worst_gross
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn defect(kind: &str, x: f64, y: f64, r: f64) -> TrueDefect {
        TrueDefect {
            kind: kind.into(),
            x_mm: x,
            y_mm: y,
            radius_mm: r,
            depth_mm: 0.5,
        }
    }

    #[test]
    fn each_true_defect_matches_one_report_within_its_reach() {
        let truth = [
            defect("hole", 0.0, 0.0, 3.0),
            defect("dent", 20.0, 0.0, 1.0),
        ];
        // Two reports at the hole (one used), one 1.5 mm from the small dent (reach 2 mm), one far off.
        let reported = [
            ("hole", [0.5, 0.0]),
            ("anomaly", [2.5, 0.0]),
            ("bump", [21.5, 0.0]),
            ("dent", [40.0, 0.0]),
        ];
        let m = match_defects(&truth, &reported);
        assert_eq!(
            m,
            DefectMatch {
                truth: 2,
                reported: 4,
                matched: 2,
                right_kind: 1
            }
        );
        assert_eq!(match_defects(&truth, &[]).matched, 0);
    }
}
