//! `stripe3d run`: the line. Frames from a source are extracted, coded and triangulated as they arrive, parts are
//! found on the belt ([`stripe3d_core::line`]) and each is inspected with its product's method the moment its
//! trailing edge has passed every sheet: one JSON line per part on stdout, the verdict into the history.

use crate::inspect::{
    ProductContext, assess_part, build_report, detect_params, history_record, load_product,
};
use crate::scan::{CodingArgs, default_grid, extract_params};
use anyhow::{Context, Result, bail};
use clap::Args;
use serde_json::json;
use std::collections::VecDeque;
use std::io::Write;
use std::path::PathBuf;
use std::sync::mpsc::{Receiver, SyncSender, TrySendError, sync_channel};
use std::time::{Duration, Instant};
use stripe3d_core::Sensor;
use stripe3d_core::accumulate::{ModelKind, Profile};
use stripe3d_core::calibrate::{Calibration, check_camera};
use stripe3d_core::characterize::{CharacterizeParams, ReferenceSource};
use stripe3d_core::code::CodedFrame;
use stripe3d_core::detect::{SurfaceRules, inspect};
use stripe3d_core::line::{
    FoundPart, FrameSource, PartParams, PartTracker, SourceFrame, crop_x, view_span_mm,
};
use stripe3d_core::scan::{ScanOptions, Scanner, finish_scan};
use stripe3d_io::cloud::write_range;
use stripe3d_io::files::prepare_dir;
use stripe3d_io::history::{History, default_path};
use stripe3d_io::report::{defects_picture, deviation_picture, write_picture, write_report};
use stripe3d_io::source::FolderSource;
use stripe3d_io::{read_calibration, read_sensor};
use stripe3d_sim::belt::{BeltSource, view_of};
use stripe3d_sim::pipeline::calibrate_sensor;
use stripe3d_sim::{RenderOptions, Scene};

/// Arguments of `stripe3d run`.
#[derive(Debug, Args)]
pub struct RunArgs {
    /// Where the frames come from: `sim:SCENE` (the simulator's belt carrying parts made from a built-in scene:
    /// `plate`, `block`, `demo`, or `defect-plates`, plates with 0, 2 or 4 seeded defects in turn), `replay:DIR` (a
    /// recorded folder of frames, read as fast as the chain takes them) or `folder:DIR` (frames read as they
    /// appear, until none has for --idle-s).
    #[arg(long, value_name = "SOURCE")]
    pub source: String,
    /// Product from the knowledge base: its file or its name in --kb (a method with a fitted reference).
    #[arg(long, value_name = "FILE|NAME")]
    pub product: String,
    /// Knowledge-base folder [default: the folder holding --product FILE, else the shipped example].
    #[arg(long, value_name = "DIR")]
    pub kb: Option<PathBuf>,
    /// Inspection history database [default: $STRIPE3D_DB, else ~/.local/share/stripe3d/history.sqlite].
    #[arg(long, value_name = "FILE")]
    pub db: Option<PathBuf>,
    /// Do not record the inspections in the history.
    #[arg(long, conflicts_with = "db")]
    pub no_history: bool,
    /// Stop after N parts (with `sim:`, the belt carries N parts) [default: sim 3, others all].
    #[arg(long, value_name = "N")]
    pub parts: Option<usize>,
    /// Stop after N frames.
    #[arg(long, value_name = "N")]
    pub frames: Option<u64>,
    /// Sensor description [default with `sim:`: the paper's set-up; needed otherwise].
    #[arg(long)]
    pub sensor: Option<PathBuf>,
    /// Calibration [default with `sim:`: calibrated from simulated plates; needed otherwise].
    #[arg(long)]
    pub calib: Option<PathBuf>,
    /// Gap between parts on the simulated belt, mm [default: the view's length along the travel and 10 mm].
    #[arg(long, value_name = "MM")]
    pub gap_mm: Option<f64>,
    /// Seed of the simulated belt's noise and defects.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Frames waiting for the chain at most; a live source's frames beyond it are dropped and counted.
    #[arg(long, default_value_t = 16)]
    pub queue: usize,
    /// With `folder:`, stop after this many seconds without a new file.
    #[arg(long, value_name = "S", default_value_t = 2.0)]
    pub idle_s: f64,
    /// Also write each part's range image, report.json and pictures to DIR/part-N/.
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Threads extracting, coding and triangulating frames [default: every core].
    #[arg(long, value_name = "N")]
    pub threads: Option<usize>,
    /// Stripe coding's measuring range and parameters (as `stripe3d scan`'s).
    #[command(flatten)]
    pub coding: CodingArgs,
}

/// A source, its sensor and calibration, as `--source` names them.
fn open_source(args: &RunArgs) -> Result<(Box<dyn FrameSource>, Sensor, Calibration)> {
    let (kind, rest) = args
        .source
        .split_once(':')
        .unwrap_or((args.source.as_str(), ""));
    let read_both = || -> Result<(Sensor, Calibration)> {
        let (Some(s), Some(c)) = (&args.sensor, &args.calib) else {
            bail!(
                "--source {}: frames from disk need --sensor sensor.toml and --calib calib.toml",
                args.source
            );
        };
        let sensor = read_sensor(s)?;
        let cal = read_calibration(c)?;
        check_camera(&cal.full.camera, &sensor.camera)
            .with_context(|| format!("{} does not belong to {}", c.display(), s.display()))?;
        Ok((sensor, cal))
    };
    match kind {
        "sim" => {
            let sensor = match &args.sensor {
                Some(p) => read_sensor(p)?,
                None => Sensor::default(),
            };
            let parts = args.parts.unwrap_or(3);
            if parts == 0 {
                bail!("--parts 0: give at least one part");
            }
            let scenes: Vec<Scene> = match rest {
                "defect-plates" => (0..parts.min(3))
                    .map(|i| Scene::defect_plate(args.seed.wrapping_add(i as u64), 2 * i))
                    .collect(),
                name => vec![Scene::builtin(name).with_context(|| {
                    format!(
                        "--source {}: no built-in scene `{name}` (give sim:plate, sim:block, sim:demo or \
                         sim:defect-plates)",
                        args.source
                    )
                })?],
            };
            let cal = match &args.calib {
                Some(c) => {
                    let cal = read_calibration(c)?;
                    check_camera(&cal.full.camera, &sensor.camera).with_context(|| {
                        format!("{} does not belong to the sensor", c.display())
                    })?;
                    cal
                }
                None => {
                    eprintln!("calibrating the simulated sensor (plates at 0-35 mm) ...");
                    calibrate_sensor(&sensor, args.seed)
                        .context("calibrating the simulated sensor")?
                }
            };
            let top = scenes
                .iter()
                .filter_map(|s| s.plate.as_ref().map(|p| p.thickness_mm))
                .fold(0.0, f64::max);
            let view = view_of(&sensor, top);
            let gap = args.gap_mm.unwrap_or(view[1] - view[0] + 10.0);
            let opts = RenderOptions {
                seed: args.seed,
                ..RenderOptions::default()
            };
            let src = BeltSource::new(&args.source, &sensor, &scenes, parts, gap, opts)
                .with_context(|| format!("--source {}", args.source))?;
            Ok((Box::new(src), sensor, cal))
        }
        "replay" | "folder" if !rest.is_empty() => {
            let (sensor, cal) = read_both()?;
            let fps = sensor.conveyor.clone().unwrap_or_default().fps;
            let watch = (kind == "folder").then(|| Duration::from_secs_f64(args.idle_s.max(0.0)));
            let src = FolderSource::new(&args.source, std::path::Path::new(rest), fps, watch)?;
            Ok((Box::new(src), sensor, cal))
        }
        _ => bail!(
            "--source {}: give sim:SCENE, replay:DIR or folder:DIR",
            args.source
        ),
    }
}

/// What one frame became.
struct Processed {
    index: u64,
    travel_mm: f64,
    coded: CodedFrame,
}

/// The frames the source delivered, and those dropped because the chain was behind.
struct Feed {
    /// Frames with their sequence number in the queue (a live source's dropped frames leave gaps in `index`).
    frames: Receiver<(u64, SourceFrame)>,
    dropped: std::sync::Arc<std::sync::atomic::AtomicU64>,
    error: std::sync::Arc<std::sync::Mutex<Option<String>>>,
}

/// Runs the source on its own thread into a queue of `capacity` frames: a live source's frames that find the queue
/// full are dropped and counted; others wait.
fn feed(mut source: Box<dyn FrameSource>, capacity: usize, max_frames: Option<u64>) -> Feed {
    let (tx, rx): (SyncSender<(u64, SourceFrame)>, _) = sync_channel(capacity.max(1));
    let dropped = std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0));
    let error = std::sync::Arc::new(std::sync::Mutex::new(None));
    let (d, e) = (dropped.clone(), error.clone());
    std::thread::spawn(move || {
        let live = source.live_rate_hz().is_some();
        let (mut n, mut queued) = (0u64, 0u64);
        loop {
            if max_frames.is_some_and(|m| n >= m) {
                return;
            }
            let frame = match source.next_frame() {
                Ok(Some(f)) => f,
                Ok(None) => return,
                Err(err) => {
                    if let Ok(mut slot) = e.lock() {
                        *slot = Some(err.to_string());
                    }
                    return;
                }
            };
            n += 1;
            if live {
                match tx.try_send((queued, frame)) {
                    Ok(()) => queued += 1,
                    Err(TrySendError::Full(_)) => {
                        d.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    }
                    Err(TrySendError::Disconnected(_)) => return,
                }
            } else if tx.send((queued, frame)).is_err() {
                return;
            } else {
                queued += 1;
            }
        }
    });
    Feed {
        frames: rx,
        dropped,
        error,
    }
}

/// One frame through the per-frame stages, with its place in the queue.
struct Worked {
    seq: u64,
    index: u64,
    travel_mm: f64,
    coded: CodedFrame,
    profile: Profile,
}

/// Extracts, codes and triangulates one frame (its travel from the encoder, else the conveyor's nominal speed).
fn work(
    scanner: &mut Scanner,
    cal: &Calibration,
    conveyor: &stripe3d_core::Conveyor,
    (w, h): (usize, usize),
    frame: SourceFrame,
) -> Result<(u64, f64, CodedFrame, Profile), String> {
    if (frame.image.width(), frame.image.height()) != (w, h) {
        return Err(format!(
            "frame {}: {}x{} pixels, but the calibrated camera has {w}x{h}",
            frame.index,
            frame.image.width(),
            frame.image.height()
        ));
    }
    let travel = frame
        .encoder_mm
        .unwrap_or_else(|| conveyor.travel_mm(frame.index as usize));
    let (mut coded, mut profile) = (CodedFrame::default(), Profile::default());
    scanner.code_and_profile_into(
        frame.image.view(),
        frame.index as usize,
        travel,
        cal,
        &mut coded,
        &mut profile,
    );
    Ok((frame.index, travel, coded, profile))
}

/// The inspection of one part: its range image cut from the frames that saw it, inspected and judged.
struct Line<'a> {
    sensor: &'a Sensor,
    cal: &'a Calibration,
    ctx: &'a ProductContext,
    method: stripe3d_kb::model::Method,
    rules: SurfaceRules,
    history: Option<History>,
    grid: [f64; 2],
    extraction: stripe3d_core::extract::Method,
    product_length_mm: f64,
    step_mm: f64,
    out: Option<PathBuf>,
}

impl Line<'_> {
    fn inspect_part(
        &mut self,
        number: usize,
        part: &FoundPart,
        kept: &VecDeque<Processed>,
    ) -> Result<serde_json::Value> {
        let frames: Vec<&Processed> = kept
            .iter()
            .filter(|p| p.index >= part.frames[0] && p.index <= part.frames[1])
            .collect();
        let mut coded: Vec<CodedFrame> = frames.iter().map(|p| p.coded.clone()).collect();
        let travel: Vec<f64> = frames.iter().map(|p| p.travel_mm).collect();
        let options = ScanOptions {
            grid_mm: self.grid,
            curvature_correction: true,
            spacetime: false,
        };
        let none: &[stripe3d_core::Image<u16>] = &[];
        let scan = finish_scan(
            &mut coded,
            none,
            &travel,
            self.sensor,
            self.cal,
            ModelKind::Full,
            self.extraction,
            &options,
        )?;
        // The part's own columns, with a margin of a gap's worth for its rim.
        let margin = PartParams::default().gap_mm;
        let range = crop_x(&scan.range, [part.x_mm[0] - margin, part.x_mm[1] + margin])
            .context("the part's range image is empty")?;
        let shape = self
            .method
            .surface
            .fitted_shape()
            .context("the product's method compares with a golden scan")?;
        let params = detect_params(
            Some(&self.method),
            self.method.surface.threshold_mm,
            Some(self.step_mm),
        );
        let inspection = inspect(
            &range,
            ReferenceSource::Fit(shape),
            &CharacterizeParams::default(),
            &mut self.rules,
            &params,
        )?;
        let assessment = assess_part(self.ctx, self.history.as_ref(), &range, &inspection)?;
        let decision = if part.complete {
            assessment.decision.name()
        } else {
            "incomplete"
        };
        let mut warnings = Vec::new();
        if part.length_mm() > 1.5 * self.product_length_mm {
            warnings.push(format!(
                "{:.1} mm long along the travel, the product {:.1} mm: parts touching each other, inspected as one",
                part.length_mm(),
                self.product_length_mm
            ));
        }
        if !part.complete {
            warnings
                .push("still in view when the stream ended: not every sheet swept it".to_string());
        }
        let part_id = format!("line-part-{number}");
        let dir = match &self.out {
            Some(root) => {
                let dir = root.join(format!("part-{number}"));
                prepare_dir(&dir)?;
                write_range(&dir, &range, json!({ "part": number }))?;
                let report = build_report(
                    &range,
                    &inspection,
                    &format!("part {number} of the line"),
                    Some((self.ctx, &assessment)),
                );
                write_report(&dir, &report)?;
                let d = &inspection.detection;
                write_picture(
                    &dir.join("defects.png"),
                    &defects_picture(&range, &d.defects),
                )?;
                write_picture(
                    &dir.join("deviation.png"),
                    &deviation_picture(
                        &range,
                        &inspection.maps.deviation_mm,
                        5.0 * params.seed_mm,
                        &d.defects,
                    ),
                )?;
                Some(dir.display().to_string())
            }
            None => None,
        };
        let mut history_id = None;
        if let Some(h) = &mut self.history {
            let record = history_record(
                part_id.clone(),
                dir.clone(),
                Some(self.ctx),
                &inspection,
                Some(&assessment),
                decision,
            );
            history_id = Some(h.record(&record)?);
        }
        let defects: Vec<serde_json::Value> = inspection
            .detection
            .defects
            .iter()
            .map(|d| {
                json!({
                    "kind": d.kind.name(),
                    "x_mm": d.centroid_mm[0],
                    "y_mm": d.centroid_mm[1],
                    "depth_mm": d.depth_mm,
                    "area_mm2": d.area_mm2,
                    "confidence": d.confidence,
                })
            })
            .collect();
        Ok(json!({
            "part": number,
            "part_id": part_id,
            "product": self.ctx.name,
            "verdict": decision,
            "complete": part.complete,
            "defects": defects,
            "diagnosis": assessment.diagnosis,
            "first_frame": part.frames[0],
            "last_frame": part.frames[1],
            "x_mm": part.x_mm,
            "history_id": history_id,
            "report_dir": dir,
            "warnings": warnings,
        }))
    }
}

/// Runs `stripe3d run`.
pub fn run(args: &RunArgs) -> Result<()> {
    let ctx =
        load_product(Some(&args.product), args.kb.as_deref())?.context("--product: no product")?;
    let (product, _, method) = ctx.kb.product_context(&ctx.name)?;
    let (method, product_length_mm) = (method.clone(), product.geometry.length_mm);
    if method.surface.fitted_shape().is_none() {
        bail!(
            "product `{}` is inspected with method `{}`, which compares parts with a golden scan; `stripe3d run` \
             inspects with a fitted reference (a plane or a quadratic): choose a product whose method fits one",
            ctx.name,
            method.name
        );
    }
    let rules = ctx.kb.surface_rules(&method)?;
    let history = if args.no_history {
        None
    } else {
        Some(History::open(
            &args.db.clone().unwrap_or_else(default_path),
        )?)
    };
    let (source, sensor, cal) = open_source(args)?;
    eprintln!("running {} for product {}", source.describe(), ctx.name);
    let (coding, range_mm) = args.coding.resolve(&cal)?;
    let extract = extract_params(&method.scan.extraction)?;
    let extraction = extract.method;
    let scanner = Scanner::new(&cal, extract, coding, ModelKind::Full)?;
    let conveyor = sensor.conveyor.clone().unwrap_or_default();
    let view = view_span_mm(&cal, [range_mm.0.max(0.0), range_mm.1]);
    // Parts ride lengthwise: a run shorter than half the product's length is debris (a stray reading, a chip on the
    // belt), not a part.
    let part_params = PartParams {
        min_length_mm: 0.5 * product_length_mm,
        ..PartParams::default()
    };
    let mut tracker = PartTracker::new(part_params, view);
    let mut line = Line {
        sensor: &sensor,
        cal: &cal,
        ctx: &ctx,
        method,
        rules,
        history,
        grid: default_grid(&sensor),
        extraction,
        product_length_mm,
        step_mm: conveyor.step_mm(),
        out: args.out.clone(),
    };
    let feed = feed(source, args.queue, args.frames);
    let (feed_error, feed_dropped) = (feed.error.clone(), feed.dropped.clone());
    let (w, h) = (sensor.camera.width as usize, sensor.camera.height as usize);
    let mut kept: VecDeque<Processed> = VecDeque::new();
    let (mut frames, mut parts, mut verdicts) = (0u64, 0usize, std::collections::BTreeMap::new());
    let started = Instant::now();
    let stdout = std::io::stdout();
    let emit = |value: serde_json::Value| -> Result<()> {
        let mut out = stdout.lock();
        writeln!(out, "{value}")?;
        out.flush()?;
        Ok(())
    };
    let mut handle = |found: Vec<FoundPart>,
                      kept: &VecDeque<Processed>,
                      parts: &mut usize,
                      verdicts: &mut std::collections::BTreeMap<String, usize>|
     -> Result<bool> {
        for part in found {
            *parts += 1;
            let value = line.inspect_part(*parts, &part, kept)?;
            if let Some(v) = value["verdict"].as_str() {
                *verdicts.entry(v.to_string()).or_insert(0) += 1;
            }
            emit(value)?;
            if args.parts.is_some_and(|n| *parts >= n) {
                return Ok(true);
            }
        }
        Ok(false)
    };
    let mut stopped = false;
    let threads = args
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()))
        .max(1);
    let inputs = std::sync::Mutex::new(feed.frames);
    let (results_tx, results) = sync_channel::<Result<Worked, String>>(args.queue.max(1));
    std::thread::scope(|scope| -> Result<()> {
        // Workers: each its own scanner, frames taken in turn from the queue, results tagged by sequence number.
        for _ in 0..threads {
            let (inputs, results_tx, mut scanner) = (&inputs, results_tx.clone(), scanner.clone());
            let (cal, conveyor) = (&cal, &conveyor);
            scope.spawn(move || {
                loop {
                    let next = match inputs.lock() {
                        Ok(rx) => rx.recv(),
                        Err(_) => return,
                    };
                    let Ok((seq, frame)) = next else {
                        return;
                    };
                    let worked = work(&mut scanner, cal, conveyor, (w, h), frame).map(
                        |(index, travel_mm, coded, profile)| Worked {
                            seq,
                            index,
                            travel_mm,
                            coded,
                            profile,
                        },
                    );
                    if results_tx.send(worked).is_err() {
                        return;
                    }
                }
            });
        }
        drop(results_tx);
        // Owned here: returning early (the parts asked for are done, or an error) drops it, and the workers stop.
        let results = results;
        // The frames in queue order, whatever order the workers finish them in.
        let mut waiting = std::collections::BTreeMap::new();
        let mut next_seq = 0u64;
        for r in results.iter() {
            let r = r.map_err(anyhow::Error::msg)?;
            waiting.insert(r.seq, r);
            while let Some(r) = waiting.remove(&next_seq) {
                next_seq += 1;
                frames += 1;
                let found = tracker.add(r.index, r.travel_mm, &r.profile);
                kept.push_back(Processed {
                    index: r.index,
                    travel_mm: r.travel_mm,
                    coded: r.coded,
                });
                if handle(found, &kept, &mut parts, &mut verdicts)? {
                    stopped = true;
                    return Ok(());
                }
                // Memory stays flat: only the frames an open part was seen in are kept.
                let oldest = tracker.oldest_open_frame().unwrap_or(r.index + 1);
                while kept.front().is_some_and(|p| p.index < oldest) {
                    kept.pop_front();
                }
            }
        }
        Ok(())
    })?;
    if let Some(e) = feed_error.lock().ok().and_then(|mut e| e.take()) {
        bail!("{e}");
    }
    if !stopped {
        let open = tracker.finish();
        handle(open, &kept, &mut parts, &mut verdicts)?;
    }
    let dropped = feed_dropped.load(std::sync::atomic::Ordering::Relaxed);
    let seconds = started.elapsed().as_secs_f64();
    eprintln!(
        "{frames} frames in {seconds:.1} s ({:.0} frames/s), {dropped} dropped; {parts} part(s): {}; {} too short to \
         be parts (debris)",
        frames as f64 / seconds.max(1e-9),
        if verdicts.is_empty() {
            "none (an empty belt)".to_string()
        } else {
            verdicts
                .iter()
                .map(|(k, v)| format!("{v} {k}"))
                .collect::<Vec<_>>()
                .join(", ")
        },
        tracker.debris
    );
    Ok(())
}
