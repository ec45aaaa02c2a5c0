//! `stripe3d inspect`: scan frames (or take a scan's range image), characterize the surface, find and measure its
//! defects, and write `report.json` with the pictures.

use crate::scan::{
    CodingArgs, ScanResult, default_grid, extract_params, frame_list, scan_frames, travel_step,
    travels, write_scan,
};
use anyhow::{Context, Result, bail};
use clap::{Args, ValueEnum};
use std::path::{Path, PathBuf};
use std::time::Instant;
use stripe3d_core::accumulate::{ModelKind, RangeImage};
use stripe3d_core::calibrate::check_camera;
use stripe3d_core::characterize::{CharacterizeParams, ReferenceShape, ReferenceSource};
use stripe3d_core::detect::{DetectParams, Detection, Inspection, SurfaceRules, inspect};
use stripe3d_io::files::{prepare_dir, read_text};
use stripe3d_io::history::{CandidateRecord, History, InspectionRecord, default_path};
use stripe3d_io::knowledge::{kb_root_of, read_kb};
use stripe3d_io::report::{
    REPORT_FORMAT, REPORT_VERSION, Report, ReportDefect, ReportDetectable, ReportKnowledgeBase,
    ReportPictures, ReportRange, ReportReference, ReportSurface, ReportUnmeasured, defects_picture,
    deviation_picture, generator, range_travel_step, range_warnings, read_range, write_picture,
    write_report,
};
use stripe3d_io::{read_calibration, read_sensor};
use stripe3d_kb::reason::{frame_origin, part_facts, recurrence};
use stripe3d_kb::{Assessment, KnowledgeBase, assess};

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
    /// Product from the knowledge base: its file (`products/NAME.toml` in a knowledge-base folder) or its name in
    /// --kb. Its method sets the reference, rules and thresholds; the verdict, diagnosis and trace follow its
    /// standards, zones, designed features and process.
    #[arg(long, value_name = "FILE|NAME")]
    pub product: Option<String>,
    /// Knowledge-base folder [default: the folder holding --product FILE, else the shipped example].
    #[arg(long, value_name = "DIR")]
    pub kb: Option<PathBuf>,
    /// Inspection history database [default: $STRIPE3D_DB, else ~/.local/share/stripe3d/history.sqlite].
    #[arg(long, value_name = "FILE")]
    pub db: Option<PathBuf>,
    /// Do not record the inspection in the history.
    #[arg(long, conflicts_with = "db")]
    pub no_history: bool,
    /// Part identifier for the history [default: made from the time].
    #[arg(long, value_name = "ID")]
    pub part_id: Option<String>,
    /// Output folder: report.json, defects.png, deviation.png (and the scan's files when frames are given).
    #[arg(long)]
    pub out: PathBuf,
    /// Frames in scan order (images or folders of them), or one range image: a `stripe3d scan` output folder or
    /// its range.json.
    #[arg(required = true, value_name = "FRAME")]
    pub frames: Vec<PathBuf>,
    /// Shape of the fitted reference surface (without --reference) [default: the product method's, else plane].
    #[arg(long, value_enum)]
    pub shape: Option<ShapeArg>,
    /// Surface rule base (FLL) to use instead of the shipped rules/surface.fll.
    #[arg(long, value_name = "FILE.fll")]
    pub rules: Option<PathBuf>,
    /// Smallest deviation that starts a defect, mm [default: the product method's, else 0.05].
    #[arg(long, value_name = "MM")]
    pub threshold_mm: Option<f64>,
    /// Conveyor position of each frame in mm, one per line [default: speed and fps of sensor.toml].
    #[arg(long)]
    pub encoder: Option<PathBuf>,
    /// Range image cell size in mm when scanning frames [default: one pixel on the belt].
    #[arg(long, value_name = "MM")]
    pub grid_mm: Option<f64>,
    /// When scanning frames: stripe coding's measuring range and parameters (as `stripe3d scan`'s).
    #[command(flatten)]
    pub coding: CodingArgs,
    /// When scanning frames, keep the heights as triangulated (see `stripe3d scan --help`).
    #[arg(long)]
    pub no_curvature_correction: bool,
    /// When scanning frames, keep each frame's stripe centres (see `stripe3d scan --help`).
    #[arg(long)]
    pub no_spacetime: bool,
    /// When scanning frames, what the sensor sees of colour frames (as `stripe3d scan --laser`) [default: auto].
    #[arg(long, value_parser = crate::extract::parse_laser)]
    pub laser: Option<stripe3d_io::images::Laser>,
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

/// The knowledge a product inspection runs with.
pub struct ProductContext {
    /// The knowledge base.
    pub kb: KnowledgeBase,
    /// Its folder (None: the shipped example).
    pub kb_dir: Option<PathBuf>,
    /// The product's name.
    pub name: String,
}

impl ProductContext {
    fn kb_label(&self) -> String {
        format!(
            "{} v{} ({})",
            self.kb.manifest.name,
            self.kb.manifest.version,
            self.kb_dir
                .as_ref()
                .map_or("shipped example".to_string(), |d| d.display().to_string())
        )
    }
}

/// Resolves `--product FILE|NAME` and `--kb DIR`.
pub fn load_product(
    product: Option<&str>,
    kb_dir: Option<&Path>,
) -> Result<Option<ProductContext>> {
    let Some(value) = product else {
        if let Some(d) = kb_dir {
            bail!(
                "--kb {}: give the product to inspect with --product NAME",
                d.display()
            );
        }
        return Ok(None);
    };
    let as_file = Path::new(value);
    let (kb, dir, name) = if as_file.is_file() {
        let dir = match kb_dir {
            Some(d) => d.to_path_buf(),
            None => kb_root_of(as_file).with_context(|| {
                format!(
                    "--product {value}: no kb.toml in the folders above it; a product file lives in the products/ \
                     folder of a knowledge base (or give --kb DIR)"
                )
            })?,
        };
        let kb = read_kb(&dir)?;
        let stem = as_file
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        (kb, Some(dir), stem)
    } else if value.contains('/') || value.ends_with(".toml") {
        bail!("--product {value}: no such file (give a product file, or a product name with --kb)");
    } else {
        match kb_dir {
            Some(d) => (read_kb(d)?, Some(d.to_path_buf()), value.to_string()),
            None => (stripe3d_kb::shipped()?, None, value.to_string()),
        }
    };
    kb.product_context(&name)
        .with_context(|| format!("--product {value}"))?;
    Ok(Some(ProductContext {
        kb,
        kb_dir: dir,
        name,
    }))
}

/// Builds the report of a finished inspection (with the knowledge base's verdict when a product was given).
pub fn build_report(
    range: &RangeImage,
    i: &Inspection,
    input: &str,
    product: Option<(&ProductContext, &Assessment)>,
) -> Report {
    let d = &i.detection;
    let (decision, reason) = match product {
        Some((_, a)) => (
            a.decision.name(),
            a.trace.first().cloned().unwrap_or_default(),
        ),
        None => verdict(d),
    };
    let cell = range.spacing_mm[0] * range.spacing_mm[1];
    let mut defects: Vec<ReportDefect> = d
        .defects
        .iter()
        .enumerate()
        .map(|(n, x)| ReportDefect::of(n, x))
        .collect();
    let mut report = Report {
        defects: Vec::new(),
        detectable: Some(ReportDetectable {
            noise_sigmas: d.detectable.sigmas,
            smallest_bump_mm: d.detectable.threshold_mm,
            smallest_dent_mm: d.detectable.threshold_mm,
            smallest_hole_mm: d.detectable.hole_mm,
            smoothed_noise_mm: d.detectable.noise_mm,
            threshold_mm: d.detectable.threshold_mm,
            threshold_raised: d.detectable.raised,
        }),
        diagnosis: None,
        features: None,
        format: REPORT_FORMAT,
        generator: generator(),
        input: input.to_string(),
        knowledge_base: None,
        pictures: Some(ReportPictures::default()),
        product: None,
        product_frame_origin_mm: None,
        range: Some(ReportRange {
            height: range.height,
            origin_mm: range.origin_mm,
            spacing_mm: range.spacing_mm,
            width: range.width,
        }),
        reference: Some(ReportReference::of(&i.reference)),
        status: "inspected",
        surface: Some(ReportSurface {
            coverage: d.coverage,
            noise_mm: i.maps.noise_mm,
            part_area_mm2: d.part_cells as f64 * cell,
            part_bbox_mm: d.part_bbox_mm,
        }),
        trace: None,
        unmeasured: Some(
            d.unmeasured
                .iter()
                .map(|u| ReportUnmeasured {
                    area_mm2: u.area_mm2,
                    reason: u.reason.clone(),
                    x_mm: u.centroid_mm[0],
                    y_mm: u.centroid_mm[1],
                })
                .collect(),
        ),
        verdict: decision.to_string(),
        verdict_reason: reason,
        version: REPORT_VERSION,
        warnings: d.warnings.clone(),
    };
    if let Some((ctx, a)) = product {
        for x in &a.defects {
            if let Some(o) = defects.get_mut(x.index) {
                o.product_xy_mm = Some(x.product_xy_mm);
                o.zone = Some(x.zone.clone());
                o.decision = Some(x.decision.name().to_string());
                o.reasons = Some(x.reasons.clone());
                o.causes = Some(x.causes.clone());
            }
        }
        for f in &a.features {
            if let Some(o) = f.defect_index.and_then(|k| defects.get_mut(k)) {
                o.designed = Some(f.name.clone());
                o.decision = Some("accept".to_string());
            }
        }
        report.product = Some(ctx.name.clone());
        report.knowledge_base = Some(ReportKnowledgeBase {
            folder: ctx.kb_dir.as_ref().map(|d| d.display().to_string()),
            name: ctx.kb.manifest.name.clone(),
            version: ctx.kb.manifest.version,
        });
        report.diagnosis = Some(a.diagnosis.clone());
        report.trace = Some(a.trace.clone());
        report.features = Some(a.features.clone());
        report.product_frame_origin_mm = Some(a.frame_origin_mm);
    }
    report.defects = defects;
    report
}

/// What `stripe3d inspect` concluded.
pub struct InspectOutcome {
    /// The measurements.
    pub inspection: Inspection,
    /// The knowledge base's verdict (with a product).
    pub assessment: Option<Assessment>,
    /// Id in the history.
    pub history_id: Option<i64>,
}

/// Parts of the same product looked at for recurring defects.
const RECENT_PARTS: usize = 20;

/// Detection's parameters for a seed threshold, with the product method's confidence where there is one.
pub fn detect_params(
    method: Option<&stripe3d_kb::model::Method>,
    threshold_mm: f64,
    travel_step_mm: Option<f64>,
) -> DetectParams {
    DetectParams {
        seed_mm: threshold_mm,
        // The default pair is 0.05 / 0.02 mm: growth at 40% of the seed threshold.
        grow_mm: 0.4 * threshold_mm,
        min_confidence: method.map_or(DetectParams::default().min_confidence, |m| {
            m.surface.min_confidence
        }),
        travel_step_mm,
        ..DetectParams::default()
    }
}

/// The knowledge base's verdict on an inspected part of `ctx`'s product, with the recurrence of its defects among
/// the product's last parts in `history`.
pub fn assess_part(
    ctx: &ProductContext,
    history: Option<&History>,
    range: &RangeImage,
    inspection: &Inspection,
) -> Result<Assessment> {
    let d = &inspection.detection;
    let origin = frame_origin(d);
    let recent = match history {
        Some(h) => h.recent_defects(&ctx.name, RECENT_PARTS)?,
        None => Vec::new(),
    };
    let rec: Vec<f64> = d
        .defects
        .iter()
        .map(|x| {
            recurrence(
                &recent,
                x.kind,
                [x.centroid_mm[0] - origin[0], x.centroid_mm[1] - origin[1]],
            )
        })
        .collect();
    let facts = part_facts(range, inspection, rec);
    Ok(assess(&ctx.kb, &ctx.name, d, &facts)?)
}

/// Runs `stripe3d inspect`.
pub fn run_inspect(args: &InspectArgs) -> Result<InspectOutcome> {
    let range_input = is_range_input(&args.frames);
    // A range image is scanned already: options of a scan would be ignored, so they are refused.
    let scan_only: Vec<&str> = [
        args.sensor.as_ref().map(|_| "--sensor"),
        args.calib.as_ref().map(|_| "--calib"),
        args.encoder.as_ref().map(|_| "--encoder"),
        args.grid_mm.map(|_| "--grid-mm"),
        args.no_curvature_correction
            .then_some("--no-curvature-correction"),
        args.no_spacetime.then_some("--no-spacetime"),
        args.laser.map(|_| "--laser"),
    ]
    .into_iter()
    .flatten()
    .chain(args.coding.given())
    .collect();
    if range_input && !scan_only.is_empty() {
        bail!(
            "{} is a range image, scanned already: {} apply only when inspecting frames (scan again with \
             `stripe3d scan` to change them)",
            args.frames[0].display(),
            scan_only.join(", ")
        );
    }
    let ctx = load_product(args.product.as_deref(), args.kb.as_deref())?;
    let method = match &ctx {
        Some(c) => Some(c.kb.product_context(&c.name)?.2.clone()),
        None => None,
    };
    let threshold_mm = args
        .threshold_mm
        .or(method.as_ref().map(|m| m.surface.threshold_mm))
        .unwrap_or(DetectParams::default().seed_mm);
    if !(threshold_mm.is_finite() && threshold_mm > 0.0) {
        bail!("--threshold-mm {threshold_mm}: give a positive height in mm");
    }
    if let Some(m) = &method {
        if m.surface.fitted_shape().is_none() && args.reference.is_none() && args.shape.is_none() {
            bail!(
                "product `{}` is inspected with method `{}`, which compares parts with a golden scan: give one with \
                 --reference DIR (or override with --shape plane)",
                ctx.as_ref().map_or("", |c| c.name.as_str()),
                m.name
            );
        }
    }
    let mut rules = match (&args.rules, &ctx, &method) {
        (Some(p), _, _) => load_rules(Some(p))?,
        (None, Some(c), Some(m)) => c.kb.surface_rules(m)?,
        _ => load_rules(None)?,
    };
    // The history is opened first: a bad database fails before a long scan.
    let mut history = if args.no_history {
        None
    } else {
        let path = args.db.clone().unwrap_or_else(default_path);
        Some(History::open(&path)?)
    };
    let golden = match &args.reference {
        Some(p) => Some(read_range(p).with_context(|| format!("--reference {}", p.display()))?),
        None => None,
    };
    // The scan's own warnings go into the report (and its verdict) with the inspection's; those of a scan made here
    // were printed when it was written.
    let (range, input, travel_step_mm, scan_warnings) = if range_input {
        let r = read_range(&args.frames[0])?;
        prepare_dir(&args.out)?;
        (
            r,
            format!("range image {}", args.frames[0].display()),
            range_travel_step(&args.frames[0]),
            range_warnings(&args.frames[0]),
        )
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
        let grid = match args
            .grid_mm
            .or(method.as_ref().and_then(|m| m.scan.grid_mm))
        {
            Some(g) if g.is_finite() && g > 0.0 => [g, g],
            Some(g) => bail!("--grid-mm {g}: give a positive size in mm"),
            None => default_grid(&sensor),
        };
        let estimator = method
            .as_ref()
            .map_or("steger".to_string(), |m| m.scan.extraction.clone());
        let (coding, range_mm) = args.coding.resolve(&cal)?;
        let res: ScanResult = scan_frames(
            &sensor,
            &cal,
            &frames,
            &travel,
            extract_params(&estimator)?,
            ModelKind::Full,
            coding,
            grid,
            !args.no_curvature_correction,
            !args.no_spacetime,
            args.laser.unwrap_or_default(),
        )?;
        write_scan(&args.out, &res, &frames, &travel, ModelKind::Full, range_mm)?;
        (
            res.scan.range,
            format!("{} frames", frames.len()),
            travel_step(&travel),
            res.scan.warnings.iter().map(|w| w.to_string()).collect(),
        )
    };
    let shape = match args.shape {
        Some(ShapeArg::Plane) => ReferenceShape::Plane,
        Some(ShapeArg::Quadratic) => ReferenceShape::Quadratic,
        None => method
            .as_ref()
            .and_then(|m| m.surface.fitted_shape())
            .unwrap_or(ReferenceShape::Plane),
    };
    let source = match &golden {
        Some(g) => ReferenceSource::Golden(g),
        None => ReferenceSource::Fit(shape),
    };
    let params = detect_params(method.as_ref(), threshold_mm, travel_step_mm);
    let started = Instant::now();
    let result = inspect(
        &range,
        source,
        &CharacterizeParams::default(),
        &mut rules,
        &params,
    );
    let seconds = started.elapsed().as_secs_f64();
    let mut inspection = match result {
        Ok(i) => i,
        Err(e) => {
            let message = e.to_string();
            write_report(&args.out, &Report::error(&message, &input))?;
            bail!(
                "{message} (wrote {})",
                args.out.join("report.json").display()
            );
        }
    };
    let own_warnings = inspection.detection.warnings.len();
    inspection
        .detection
        .warnings
        .extend(scan_warnings.iter().map(|w| format!("scan: {w}")));
    let d = &inspection.detection;
    let assessment = match &ctx {
        Some(c) => Some(assess_part(c, history.as_ref(), &range, &inspection)?),
        None => None,
    };
    let both = ctx.as_ref().zip(assessment.as_ref());
    write_report(&args.out, &build_report(&range, &inspection, &input, both))?;
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
    let (decision, reason) = match &assessment {
        Some(a) => (
            a.decision.name(),
            a.trace.first().cloned().unwrap_or_default(),
        ),
        None => verdict(d),
    };
    say!(
        "inspected {input} in {:.0} ms: {}",
        seconds * 1000.0,
        decision.to_uppercase()
    );
    if let Some(c) = &ctx {
        say!("  product {} with knowledge base {}", c.name, c.kb_label());
    }
    say!("  {reason}");
    let designed: Vec<Option<&str>> = (0..d.defects.len())
        .map(|k| {
            assessment.as_ref().and_then(|a| {
                a.features
                    .iter()
                    .find(|f| f.defect_index == Some(k))
                    .map(|f| f.name.as_str())
            })
        })
        .collect();
    for (n, x) in d.defects.iter().enumerate() {
        say!(
            "  {:>2}. {:<9} at ({:7.2}, {:7.2}) mm  area {:7.2} mm²  {} {:.3} mm  volume {:7.3} mm³  confidence {:.2}{}",
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
            x.confidence,
            designed[n]
                .map(|f| format!("  (designed: {f})"))
                .unwrap_or_default()
        );
    }
    if let Some(a) = &assessment {
        for line in a.trace.iter().skip(1) {
            say!("  | {line}");
        }
    }
    for u in &d.unmeasured {
        say!(
            "  not measured: {:.2} mm² at ({:.1}, {:.1}) mm: {}",
            u.area_mm2,
            u.centroid_mm[0],
            u.centroid_mm[1],
            u.reason
        );
    }
    let unprinted = if range_input {
        d.warnings.len()
    } else {
        own_warnings
    };
    for w in &d.warnings[..unprinted] {
        eprintln!("warning: {w}");
    }
    let mut history_id = None;
    if let Some(h) = &mut history {
        let part_id = args.part_id.clone().unwrap_or_else(|| {
            let t = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .unwrap_or_default();
            format!("part-{}-{:03}", t.as_secs(), t.subsec_millis())
        });
        let dir = args
            .out
            .canonicalize()
            .unwrap_or_else(|_| args.out.clone())
            .display()
            .to_string();
        let record = history_record(
            part_id,
            Some(dir),
            ctx.as_ref(),
            &inspection,
            assessment.as_ref(),
            decision,
        );
        let id = h.record(&record)?;
        say!(
            "recorded as inspection {id} (part {}) in {}",
            record.part_id,
            h.path().display()
        );
        history_id = Some(id);
    }
    say!(
        "wrote {}: report.json, defects.png (outlined defects), deviation.png (blue below, red above the reference)",
        args.out.display()
    );
    Ok(InspectOutcome {
        inspection,
        assessment,
        history_id,
    })
}

/// What the history keeps of an inspection.
pub fn history_record(
    part_id: String,
    report_dir: Option<String>,
    ctx: Option<&ProductContext>,
    inspection: &Inspection,
    assessment: Option<&Assessment>,
    decision: &str,
) -> InspectionRecord {
    let d = &inspection.detection;
    let context = ctx.and_then(|c| c.kb.product_context(&c.name).ok());
    let designed_of = |k: usize| {
        assessment.and_then(|a| {
            a.features
                .iter()
                .find(|f| f.defect_index == Some(k))
                .map(|f| f.name.clone())
        })
    };
    InspectionRecord {
        part_id,
        product: ctx.map(|c| c.name.clone()),
        process: context.map(|c| c.1.name.clone()),
        method: context.map(|c| c.2.name.clone()),
        kb_name: ctx.map(|c| c.kb.manifest.name.clone()),
        kb_version: ctx.map(|c| c.kb.manifest.version),
        verdict: decision.to_string(),
        coverage: d.coverage,
        diagnosis: assessment
            .map(|a| {
                a.diagnosis
                    .iter()
                    .map(|c| (c.cause.clone(), c.certainty))
                    .collect()
            })
            .unwrap_or_default(),
        trace: assessment.map(|a| a.trace.clone()).unwrap_or_default(),
        report_dir,
        frame_origin_mm: frame_origin(d),
        candidates: d
            .candidates
            .iter()
            .map(|c| CandidateRecord {
                candidate: c.clone(),
                defect_id: c.defect.map(|k| k + 1),
                designed: c.defect.and_then(designed_of),
                depth_mm: c.defect.and_then(|k| d.defects.get(k)).map(|x| x.depth_mm),
                volume_mm3: c
                    .defect
                    .and_then(|k| d.defects.get(k))
                    .map(|x| x.volume_mm3),
            })
            .collect(),
    }
}
