//! `stripe3d inspect`: scan frames (or take a scan's range image), characterize the surface, find and measure its
//! defects, and write `report.json` with the pictures.

use crate::scan::{ScanResult, default_grid, frame_list, scan_frames, travels, write_scan};
use anyhow::{Context, Result, bail};
use clap::{Args, ValueEnum};
use serde_json::{Value, json};
use std::path::{Path, PathBuf};
use std::time::Instant;
use stripe3d_core::accumulate::{ModelKind, RangeImage};
use stripe3d_core::calibrate::check_camera;
use stripe3d_core::characterize::{
    CharacterizeParams, ReferenceInfo, ReferenceShape, ReferenceSource,
};
use stripe3d_core::detect::{DetectParams, Detection, Inspection, SurfaceRules, inspect};
use stripe3d_io::files::{prepare_dir, read_text};
use stripe3d_io::report::{
    defects_picture, deviation_picture, read_range, write_picture, write_report,
};
use stripe3d_io::{read_calibration, read_sensor};

/// Shape of the fitted reference surface.
#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum ShapeArg {
    /// A plane (flat parts).
    Plane,
    /// A quadratic (gently curved parts).
    Quadratic,
}

/// Arguments of `stripe3d inspect`.
#[derive(Debug, Args)]
pub struct InspectArgs {
    /// Sensor description (needed with frames).
    #[arg(long)]
    pub sensor: Option<PathBuf>,
    /// Calibration written by `stripe3d calibrate` (needed with frames).
    #[arg(long)]
    pub calib: Option<PathBuf>,
    /// Golden scan of a good part: a `stripe3d scan` output folder or its range.json. Without it, the part's own
    /// top surface is fitted (see --shape).
    #[arg(long, value_name = "DIR")]
    pub reference: Option<PathBuf>,
    /// Product description from the knowledge base (nominal model, tolerances).
    #[arg(long, value_name = "FILE")]
    pub product: Option<PathBuf>,
    /// Output folder: report.json, defects.png, deviation.png (and the scan's files when frames are given).
    #[arg(long)]
    pub out: PathBuf,
    /// Frames in scan order (images or folders of them), or one range image: a `stripe3d scan` output folder or
    /// its range.json.
    #[arg(required = true, value_name = "FRAME")]
    pub frames: Vec<PathBuf>,
    /// Shape of the fitted reference surface (without --reference).
    #[arg(long, value_enum, default_value = "plane")]
    pub shape: ShapeArg,
    /// Surface rule base (FLL) to use instead of the shipped rules/surface.fll.
    #[arg(long, value_name = "FILE.fll")]
    pub rules: Option<PathBuf>,
    /// Smallest deviation that starts a defect, mm.
    #[arg(long, default_value_t = DetectParams::default().seed_mm)]
    pub threshold_mm: f64,
    /// Conveyor position of each frame in mm, one per line [default: speed and fps of sensor.toml].
    #[arg(long)]
    pub encoder: Option<PathBuf>,
    /// Range image cell size in mm when scanning frames [default: one pixel on the belt].
    #[arg(long, value_name = "MM")]
    pub grid_mm: Option<f64>,
}

fn is_range_input(frames: &[PathBuf]) -> bool {
    frames.len() == 1
        && (frames[0].join("range.json").is_file()
            || frames[0]
                .extension()
                .is_some_and(|e| e.eq_ignore_ascii_case("json")))
}

fn load_rules(path: Option<&Path>) -> Result<SurfaceRules> {
    match path {
        None => Ok(SurfaceRules::shipped()?),
        Some(p) => {
            let text = read_text(p)?;
            let engine = stripe3d_fuzzy::fll::read(&text)
                .with_context(|| format!("{}: not a usable FLL rule base", p.display()))?;
            SurfaceRules::from_engine(engine)
                .with_context(|| format!("{}: not a surface rule base", p.display()))
        }
    }
}

/// The decision without a product's tolerances: any defect rejects, an inspection that could not see the whole
/// part is incomplete. (The knowledge base refines this with tolerances, zones and rework.)
pub fn verdict(d: &Detection) -> (&'static str, String) {
    if !d.defects.is_empty() {
        (
            "reject",
            format!(
                "{} defect(s) found (no product tolerances given: every defect rejects)",
                d.defects.len()
            ),
        )
    } else if !d.warnings.is_empty() {
        (
            "incomplete",
            format!("no defect found, but: {}", d.warnings.join("; ")),
        )
    } else {
        ("accept", "no defect found on the measured surface".into())
    }
}

fn defect_json(n: usize, d: &stripe3d_core::detect::Defect) -> Value {
    let e = &d.evidence;
    json!({
        "id": n + 1,
        "kind": d.kind.name(),
        "x_mm": d.centroid_mm[0],
        "y_mm": d.centroid_mm[1],
        "area_mm2": d.area_mm2,
        "depth_mm": d.depth_mm,
        "volume_mm3": d.volume_mm3,
        "bbox_mm": d.bbox_mm,
        "confidence": d.confidence,
        "bottom_seen": d.bottom_seen,
        "evidence": {
            "curvature_per_mm": e.curvature_per_mm,
            "direction": e.direction,
            "gap_mm": e.gap_mm,
            "height_similarity_mm": e.height_similarity_mm,
            "elongation": e.elongation,
            "edge_notch_mm": e.edge_notch_mm,
            "cells": e.cells,
        },
    })
}

fn reference_json(r: &ReferenceInfo) -> Value {
    match r {
        ReferenceInfo::Fitted(f) => json!({
            "kind": format!("fitted {}", f.shape.name()),
            "centre_mm": f.centre_mm,
            "coefficients": f.coefficients,
            "coefficients_meaning": "z = c0 + c1 x' + c2 y' + c3 x'^2 + c4 x'y' + c5 y'^2, x' = (x - centre) / 10 mm",
            "sigma_mm": f.sigma_mm,
            "inlier_share": f.inlier_share,
        }),
        ReferenceInfo::Golden(g) => json!({
            "kind": "golden scan",
            "dx_mm": g.dx_mm,
            "dy_mm": g.dy_mm,
            "theta_rad": g.theta_rad,
            "dz_mm": g.dz_mm,
            "centre_mm": g.centre_mm,
            "mean_clipped_difference_mm": g.mean_difference_mm,
            "overlap": g.overlap,
        }),
    }
}

/// Builds the report of a finished inspection.
pub fn report_json(range: &RangeImage, i: &Inspection, input: &str) -> Value {
    let d = &i.detection;
    let (decision, reason) = verdict(d);
    let cell = range.spacing_mm[0] * range.spacing_mm[1];
    json!({
        "format": "stripe3d-report",
        "version": 1,
        "generator": format!("stripe3d {}", env!("CARGO_PKG_VERSION")),
        "status": "inspected",
        "input": input,
        "verdict": decision,
        "verdict_reason": reason,
        "defects": d.defects.iter().enumerate().map(|(n, x)| defect_json(n, x)).collect::<Vec<_>>(),
        "unmeasured": d.unmeasured.iter().map(|u| json!({
            "x_mm": u.centroid_mm[0], "y_mm": u.centroid_mm[1], "area_mm2": u.area_mm2, "reason": u.reason,
        })).collect::<Vec<_>>(),
        "warnings": d.warnings,
        "reference": reference_json(&i.reference),
        "surface": {
            "part_area_mm2": d.part_cells as f64 * cell,
            "coverage": d.coverage,
            "noise_mm": i.maps.noise_mm,
        },
        "range": {
            "width": range.width, "height": range.height,
            "origin_mm": range.origin_mm, "spacing_mm": range.spacing_mm,
        },
        "pictures": {
            "defects": "defects.png",
            "deviation": "deviation.png",
            "legend": "defects.png: heights colour-mapped, grey = not measured; outlines by kind (red bump, blue dent, \
                       magenta hole, cyan scratch, orange edge chip, white anomaly), labelled number + initial. \
                       deviation.png: blue below the reference, red above, full colour at 5 x the detection threshold.",
        },
    })
}

fn error_report(message: &str, input: &str) -> Value {
    json!({
        "format": "stripe3d-report",
        "version": 1,
        "generator": format!("stripe3d {}", env!("CARGO_PKG_VERSION")),
        "status": "error",
        "input": input,
        "verdict": "not-inspected",
        "verdict_reason": message,
        "defects": [],
        "warnings": [message],
    })
}

/// Runs `stripe3d inspect`.
pub fn run_inspect(args: &InspectArgs) -> Result<Inspection> {
    if let Some(p) = &args.product {
        bail!(
            "--product {}: product models come with the knowledge base, which this build does not have yet; inspect \
             against the part's own fitted surface (default) or a golden scan (--reference DIR)",
            p.display()
        );
    }
    if !(args.threshold_mm.is_finite() && args.threshold_mm > 0.0) {
        bail!(
            "--threshold-mm {}: give a positive height in mm",
            args.threshold_mm
        );
    }
    let mut rules = load_rules(args.rules.as_deref())?;
    let golden = match &args.reference {
        Some(p) => Some(read_range(p).with_context(|| format!("--reference {}", p.display()))?),
        None => None,
    };
    let (range, input) = if is_range_input(&args.frames) {
        let r = read_range(&args.frames[0])?;
        prepare_dir(&args.out)?;
        (r, format!("range image {}", args.frames[0].display()))
    } else {
        let (Some(sensor_path), Some(calib_path)) = (&args.sensor, &args.calib) else {
            bail!(
                "inspecting frames needs --sensor sensor.toml and --calib calib.toml (or give one range image)"
            );
        };
        let sensor = read_sensor(sensor_path)?;
        let cal = read_calibration(calib_path)?;
        check_camera(&cal.full.camera, &sensor.camera).with_context(|| {
            format!(
                "{} does not belong to {}",
                calib_path.display(),
                sensor_path.display()
            )
        })?;
        let frames = frame_list(&args.frames)?;
        let travel = travels(&sensor, args.encoder.as_deref(), frames.len())?;
        let grid = match args.grid_mm {
            Some(g) if g.is_finite() && g > 0.0 => [g, g],
            Some(g) => bail!("--grid-mm {g}: give a positive size in mm"),
            None => default_grid(&sensor),
        };
        let range_mm = cal.coding_range_mm();
        let res: ScanResult = scan_frames(
            &sensor,
            &cal,
            &frames,
            &travel,
            "steger",
            ModelKind::Full,
            range_mm,
            grid,
        )?;
        write_scan(&args.out, &res, &frames, &travel, ModelKind::Full, range_mm)?;
        (res.range, format!("{} frames", frames.len()))
    };
    let source = match &golden {
        Some(g) => ReferenceSource::Golden(g),
        None => ReferenceSource::Fit(match args.shape {
            ShapeArg::Plane => ReferenceShape::Plane,
            ShapeArg::Quadratic => ReferenceShape::Quadratic,
        }),
    };
    let params = DetectParams {
        seed_mm: args.threshold_mm,
        // The default pair is 0.05 / 0.02 mm: growth at 40% of the seed threshold.
        grow_mm: 0.4 * args.threshold_mm,
        ..DetectParams::default()
    };
    let started = Instant::now();
    let result = inspect(
        &range,
        source,
        &CharacterizeParams::default(),
        &mut rules,
        &params,
    );
    let seconds = started.elapsed().as_secs_f64();
    let inspection = match result {
        Ok(i) => i,
        Err(e) => {
            let message = e.to_string();
            write_report(&args.out, &error_report(&message, &input))?;
            bail!(
                "{message} (wrote {})",
                args.out.join("report.json").display()
            );
        }
    };
    let d = &inspection.detection;
    write_report(&args.out, &report_json(&range, &inspection, &input))?;
    write_picture(
        &args.out.join("defects.png"),
        &defects_picture(&range, &d.defects),
    )?;
    write_picture(
        &args.out.join("deviation.png"),
        &deviation_picture(
            &range,
            &inspection.maps.deviation_mm,
            5.0 * params.seed_mm,
            &d.defects,
        ),
    )?;
    let (decision, reason) = verdict(d);
    println!(
        "inspected {input} in {:.0} ms: {}",
        seconds * 1000.0,
        decision.to_uppercase()
    );
    println!("  {reason}");
    for (n, x) in d.defects.iter().enumerate() {
        println!(
            "  {:>2}. {:<9} at ({:7.2}, {:7.2}) mm  area {:7.2} mm²  {} {:.3} mm  volume {:7.3} mm³  confidence {:.2}",
            n + 1,
            x.kind.name(),
            x.centroid_mm[0],
            x.centroid_mm[1],
            x.area_mm2,
            if x.kind == stripe3d_core::detect::DefectKind::Bump {
                "height"
            } else {
                "depth "
            },
            x.depth_mm,
            x.volume_mm3,
            x.confidence
        );
    }
    for u in &d.unmeasured {
        println!(
            "  not measured: {:.2} mm² at ({:.1}, {:.1}) mm: {}",
            u.area_mm2, u.centroid_mm[0], u.centroid_mm[1], u.reason
        );
    }
    for w in &d.warnings {
        eprintln!("warning: {w}");
    }
    println!(
        "wrote {}: report.json, defects.png (outlined defects), deviation.png (blue below, red above the reference)",
        args.out.display()
    );
    Ok(inspection)
}
