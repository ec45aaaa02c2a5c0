//! `stripe3d simulate` and `stripe3d demo`.

use anyhow::{Context, Result, bail};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;
use serde_json::json;
use std::path::{Path, PathBuf};
use std::time::Instant;
use stripe3d_core::Sensor;
use stripe3d_io::encoder::read_encoder;
use stripe3d_io::files::{prepare_dir, read_text};
use stripe3d_io::images::write_grey_png;
use stripe3d_io::truth::{STRIPES_CSV_HEADER, append_stripes_csv, write_defects, write_height_map};
use stripe3d_io::{read_scene, read_sensor, scene_to_toml, sensor_to_toml, write_atomic};
use stripe3d_sim::{RenderOptions, Scene, Simulator};

/// Frames rendered beyond one stripe pitch of travel by default, so the bands of neighbouring stripes overlap
/// and the range image has no empty seams between them.
const SWEEP_OVERLAP_FRAMES: usize = 2;

/// Most frames one run renders.
const MAX_FRAMES: usize = 100_000;

/// Arguments of `stripe3d simulate`.
#[derive(Debug, Args)]
pub struct SimulateArgs {
    /// Built-in scene name (demo, plate, block, belt) or a scene TOML file.
    #[arg(long, default_value = "demo")]
    pub scene: String,
    /// Number of frames [default: enough for the stripes to sweep one stripe pitch of the part, and two more].
    #[arg(long)]
    pub frames: Option<usize>,
    /// File of conveyor positions in mm, one per frame (overrides --frames and the conveyor speed).
    #[arg(long)]
    pub encoder: Option<PathBuf>,
    /// Sensor description [default: the paper's set-up].
    #[arg(long)]
    pub sensor: Option<PathBuf>,
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
    /// Seed of all random effects.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Bits per pixel (8, 10, 12, 16), overriding the sensor's.
    #[arg(long)]
    pub bits: Option<u8>,
    /// Rays per pixel side (1 to 8).
    #[arg(long, default_value_t = 1)]
    pub supersample: u32,
    /// Render without shot/read noise and speckle.
    #[arg(long)]
    pub no_noise: bool,
}

/// What a simulation run wrote.
pub struct SimulationSummary {
    pub frames: usize,
    pub truth_points: usize,
    pub seconds: f64,
}

pub(crate) fn load_scene(name: &str) -> Result<Scene> {
    if let Some(s) = Scene::builtin(name) {
        return Ok(s);
    }
    let path = Path::new(name);
    if !path.exists() {
        bail!(
            "--scene {name}: no built-in scene of that name ({}) and no such file",
            Scene::BUILTIN_NAMES.join(", ")
        );
    }
    Ok(read_scene(path)?)
}

fn travels(args: &SimulateArgs, sensor: &Sensor) -> Result<Vec<f64>> {
    if let Some(enc) = &args.encoder {
        return Ok(read_encoder(enc, MAX_FRAMES)?);
    }
    let conveyor = sensor.conveyor.clone().unwrap_or_default();
    let step = conveyor.speed_mm_s / conveyor.fps;
    let frames = match args.frames {
        Some(0) => bail!("--frames 0: render at least one frame"),
        Some(n) if n > MAX_FRAMES => bail!("--frames {n}: at most {MAX_FRAMES}"),
        Some(n) => n,
        None if step > 0.0 => {
            stripe3d_sim::pipeline::frames_for_sweep(sensor, SWEEP_OVERLAP_FRAMES).clamp(1, 1000)
        }
        None => 1,
    };
    Ok((0..frames).map(|k| conveyor.travel_mm(k)).collect())
}

/// Runs `stripe3d simulate`.
pub fn simulate(args: &SimulateArgs) -> Result<SimulationSummary> {
    let mut sensor = match &args.sensor {
        Some(p) => read_sensor(p)?,
        None => Sensor::default(),
    };
    if let Some(b) = args.bits {
        sensor.camera.bits = b;
        sensor.validate().context("--bits")?;
    }
    let scene = load_scene(&args.scene)?;
    let travel = travels(args, &sensor)?;
    let opts = RenderOptions {
        noise: !args.no_noise,
        speckle: !args.no_noise,
        supersample: args.supersample,
        seed: args.seed,
        ..RenderOptions::default()
    };
    let sim =
        Simulator::new(&sensor, &scene, opts.clone()).context("cannot set up the simulation")?;
    let out = &args.out;
    let frames_dir = out.join("frames");
    let truth_dir = out.join("truth");
    for d in [out, &frames_dir, &truth_dir] {
        prepare_dir(d)?;
    }
    let start = Instant::now();
    let bar = ProgressBar::new(travel.len() as u64).with_style(
        ProgressStyle::with_template("{msg} [{bar:40}] {pos}/{len} frames ({eta})")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar.set_message(format!("rendering {}", scene.name));
    let bits = sensor.camera.bits;
    let results: Vec<Result<(String, usize)>> = travel
        .par_iter()
        .enumerate()
        .map(|(k, &t)| {
            let frame = sim.render(k, t);
            write_grey_png(
                &frames_dir.join(format!("frame_{k:05}.png")),
                &frame.image,
                bits,
            )?;
            let mut csv = String::new();
            append_stripes_csv(&mut csv, k, &frame.truth);
            bar.inc(1);
            Ok((csv, frame.truth.len()))
        })
        .collect();
    bar.finish_and_clear();
    let mut csv = format!("{STRIPES_CSV_HEADER}\n");
    let mut points = 0;
    for r in results {
        let (part, n) = r?;
        csv.push_str(&part);
        points += n;
    }
    let seconds = start.elapsed().as_secs_f64();
    write_atomic(&truth_dir.join("stripes.csv"), csv.as_bytes())?;
    write_height_map(&truth_dir, sim.height_field())?;
    write_defects(&truth_dir, sim.defects())?;
    write_atomic(&out.join("sensor.toml"), sensor_to_toml(&sensor).as_bytes())?;
    write_atomic(&out.join("scene.toml"), scene_to_toml(&scene).as_bytes())?;
    let frames: Vec<_> = travel
        .iter()
        .enumerate()
        .map(|(k, t)| json!({"index": k, "file": format!("frames/frame_{k:05}.png"), "travel_mm": t}))
        .collect();
    let manifest = json!({
        "generator": format!("stripe3d {} simulate", env!("CARGO_PKG_VERSION")),
        "scene": scene.name,
        "seed": args.seed,
        "options": opts,
        "bits": bits,
        "image_size": [sensor.camera.width, sensor.camera.height],
        "stripes": sensor.laser.stripes,
        "frames": frames,
        "truth": {
            "stripes_csv": "truth/stripes.csv",
            "stripes_columns": {
                "frame": "frame index", "row": "image row", "stripe": "stripe index, 0 = smallest x at the belt",
                "u": "sub-pixel column where the row's camera ray meets the lit surface on the sheet's centre plane (pixel centres at integers)",
                "x_mm": "world x", "y_mm": "world y", "z_mm": "world z (height above the belt)",
                "part_x_mm": "part x = world x - travel (part y = world y, part z = world z)"
            },
            "points": points,
            "heightmap": "truth/heightmap.tiff",
            "heightmap_index": "truth/heightmap.json",
            "defects": "truth/defects.json",
        },
        "render_seconds": seconds,
    });
    write_atomic(
        &out.join("manifest.json"),
        serde_json::to_string_pretty(&manifest)?.as_bytes(),
    )?;
    Ok(SimulationSummary {
        frames: travel.len(),
        truth_points: points,
        seconds,
    })
}

/// Runs `stripe3d demo`: simulation, extraction, calibration and scanning of the demo scene.
pub fn demo(out: &Path) -> Result<()> {
    let sim_dir = out.join("simulation");
    say!(
        "stripe3d demo: rendering the demo part (80 x 60 mm plate with a step, a boss, a designed hole,"
    );
    say!("a printed mark, a glossy patch, and a bump, a dent and a through-hole as defects) ...");
    let args = SimulateArgs {
        scene: "demo".into(),
        frames: None,
        encoder: None,
        sensor: None,
        out: sim_dir.clone(),
        seed: 1,
        bits: None,
        supersample: 1,
        no_noise: false,
    };
    let s = simulate(&args)?;
    say!(
        "rendered {} frames ({:.0} frames/s on {} threads) with {} ground-truth stripe points",
        s.frames,
        s.frames as f64 / s.seconds.max(1e-9),
        rayon::current_num_threads(),
        s.truth_points
    );
    say!("wrote {}:", sim_dir.display());
    say!("  frames/frame_NNNNN.png   the camera frames");
    say!(
        "  truth/stripes.csv        exact sub-pixel stripe centres for every row, stripe and frame"
    );
    say!(
        "  truth/heightmap.tiff     the part's true height map (float32 mm; heightmap.png to look at)"
    );
    say!("  truth/defects.json       the defects put into the part");
    say!("  sensor.toml, scene.toml, manifest.json");
    extract_demo(out, &sim_dir, s.frames)?;
    scan_demo(out, &sim_dir)?;
    inspect_demo(out, &sim_dir)?;
    say!(
        "next: `stripe3d history --db {db}`, `stripe3d feedback ... --db {db}`, `stripe3d learn --product demo-bracket \
         --db {db} --out my-kb-v2`, `stripe3d kb check demo-bracket` (see the README)",
        db = out.join("history.sqlite").display()
    );
    Ok(())
}

/// Calibration plates of the demo, mm: every stripe is seen at three of them.
const DEMO_PLATES_MM: [f64; 6] = [0.0, 5.0, 10.0, 20.0, 30.0, 35.0];

/// The calibration and scanning stages of the demo: plate images at known heights, `calibrate`, then `scan` of the
/// demo frames, with the range image compared to the true height map.
fn scan_demo(out: &Path, sim_dir: &Path) -> Result<()> {
    use crate::scan::{CalibrateArgs, run_calibrate};
    let sensor_path = sim_dir.join("sensor.toml");
    let sensor = read_sensor(&sensor_path)?;
    let cal_dir = out.join("calibration");
    prepare_dir(&cal_dir)?;
    say!(
        "rendering a flat calibration plate at {DEMO_PLATES_MM:?} mm (gauge blocks under a matte plate) ..."
    );
    let planes: Vec<String> = DEMO_PLATES_MM
        .par_iter()
        .enumerate()
        .map(|(i, &z)| -> Result<String> {
            let scene = if z == 0.0 {
                Scene::empty_belt()
            } else {
                Scene::covering_plate(z)
            };
            let opts = RenderOptions {
                seed: 1000 + i as u64,
                ..RenderOptions::default()
            };
            let frame = Simulator::new(&sensor, &scene, opts)?.render(0, 0.0);
            let path = cal_dir.join(format!("plate-{z}mm.png"));
            write_grey_png(&path, &frame.image, sensor.camera.bits)?;
            Ok(format!("{z}:{}", path.display()))
        })
        .collect::<Result<_>>()?;
    let calib = out.join("calib.toml");
    run_calibrate(&CalibrateArgs {
        sensor: sensor_path,
        planes,
        out: calib.clone(),
        method: "steger".into(),
        laser: None,
    })?;
    let scan_dir = out.join("scan");
    let res = scan_simulation(sim_dir, &calib, &scan_dir)?;
    // Against the truth: every triangulated point whose true surface is smooth around it.
    let scene = load_scene("demo")?;
    let sim = Simulator::new(&sensor, &scene, RenderOptions::ideal())?;
    let hf = sim.height_field();
    let (mut sum, mut n, mut wrong) = (0.0, 0usize, 0usize);
    for p in res.profiles.iter().flat_map(|p| &p.points) {
        let z0 = hf.height_at(p.x_mm, p.y_mm);
        let smooth = [(-0.5, 0.0), (0.5, 0.0), (0.0, -0.5), (0.0, 0.5)]
            .iter()
            .all(|(dx, dy)| (hf.height_at(p.x_mm + dx, p.y_mm + dy) - z0).abs() < 0.15);
        if !smooth {
            continue;
        }
        let e = p.z_mm - z0;
        if e.abs() > 0.5 {
            wrong += 1;
            continue;
        }
        sum += e * e;
        n += 1;
    }
    say!(
        "against the true height map: RMS height error {:.4} mm over {n} points on smooth surfaces; {wrong} points more than 0.5 mm off (a wrong stripe index)",
        (sum / n.max(1) as f64).sqrt()
    );
    Ok(())
}

/// `stripe3d scan` of a simulation folder's frames with its sensor, the full model and the defaults.
fn scan_simulation(sim_dir: &Path, calib: &Path, out: &Path) -> Result<crate::scan::ScanResult> {
    use crate::scan::{ModelArg, ScanArgs, run_scan};
    run_scan(&ScanArgs {
        sensor: sim_dir.join("sensor.toml"),
        calib: calib.to_path_buf(),
        out: out.to_path_buf(),
        frames: vec![sim_dir.join("frames")],
        encoder: None,
        grid_mm: None,
        model: ModelArg::Full,
        method: "steger".into(),
        coding: crate::scan::CodingArgs::default(),
        cut_asymmetry: stripe3d_core::extract::DEFAULT_CUT_ASYMMETRY,
        no_curvature_correction: false,
        no_spacetime: false,
        laser: None,
    })
}

/// The inspection stage of the demo: a golden part (the demo part without its defects) is rendered and scanned,
/// and the demo scan is inspected against it; the defects found are compared with the ones put in.
fn inspect_demo(out: &Path, sim_dir: &Path) -> Result<()> {
    use crate::inspect::{InspectArgs, run_inspect};
    use stripe3d_sim::scene::Feature;
    let mut golden = load_scene("demo")?;
    golden.name = "demo-golden".into();
    golden.features.retain(|f| {
        !matches!(
            f,
            Feature::Bump { .. }
                | Feature::Dent { .. }
                | Feature::Scratch { .. }
                | Feature::Hole {
                    designed: false,
                    ..
                }
        )
    });
    let golden_sim = out.join("golden/simulation");
    say!("rendering a golden part (the demo part without its defects) for reference ...");
    let golden_toml = out.join("golden/scene.toml");
    prepare_dir(&out.join("golden"))?;
    write_atomic(&golden_toml, scene_to_toml(&golden).as_bytes())?;
    simulate(&SimulateArgs {
        scene: golden_toml.display().to_string(),
        frames: None,
        encoder: None,
        sensor: None,
        out: golden_sim.clone(),
        seed: 7,
        bits: None,
        supersample: 1,
        no_noise: false,
    })?;
    let golden_scan = out.join("golden/scan");
    scan_simulation(&golden_sim, &out.join("calib.toml"), &golden_scan)?;
    say!(
        "inspecting the demo scan as product `demo-bracket` of the shipped knowledge base, against the golden scan ..."
    );
    // The demo's history starts empty each run: the same part inspected again would count as a recurring defect.
    for f in ["history.sqlite", "history.sqlite-wal", "history.sqlite-shm"] {
        let p = out.join(f);
        if p.exists() {
            std::fs::remove_file(&p).with_context(|| format!("{}: cannot remove", p.display()))?;
        }
    }
    let outcome = run_inspect(&InspectArgs {
        sensor: None,
        calib: None,
        reference: Some(golden_scan),
        product: Some("demo-bracket".into()),
        kb: None,
        db: Some(out.join("history.sqlite")),
        no_history: false,
        part_id: Some("demo-1".into()),
        out: out.join("inspection"),
        frames: vec![out.join("scan")],
        shape: None,
        rules: None,
        threshold_mm: None,
        encoder: None,
        grid_mm: None,
        coding: crate::scan::CodingArgs::default(),
        no_curvature_correction: false,
        no_spacetime: false,
        laser: None,
    })?;
    let inspection = &outcome.inspection;
    let sensor = read_sensor(&sim_dir.join("sensor.toml"))?;
    let truth = Simulator::new(&sensor, &load_scene("demo")?, RenderOptions::ideal())?
        .defects()
        .to_vec();
    // Designed features are not defects: score what the knowledge base calls defects.
    let found: Vec<_> = match &outcome.assessment {
        Some(a) => a
            .defects
            .iter()
            .map(|x| inspection.detection.defects[x.index].clone())
            .collect(),
        None => inspection.detection.defects.clone(),
    };
    if let Some(id) = outcome.history_id {
        say!(
            "judge it: stripe3d feedback {id} --db {} --confirm N | --false-alarm N | --missed X,Y --kind K | --reviewed",
            out.join("history.sqlite").display()
        );
    }
    let outcome = stripe3d_sim::batch::match_defects(&truth, &found);
    for m in &outcome.matches {
        let t = &m.truth;
        match &m.found {
            Some(f) => say!(
                "  truth {} at ({:.1}, {:.1}) mm, {:.2} mm: found as {} {:.2} mm off, depth {:.3} mm, area {:.1} vs {:.1} mm²",
                t.kind,
                t.x_mm,
                t.y_mm,
                t.depth_mm,
                f.kind.name(),
                (f.centroid_mm[0] - t.x_mm).hypot(f.centroid_mm[1] - t.y_mm),
                f.depth_mm,
                f.area_mm2,
                t.area_mm2
            ),
            None => say!(
                "  truth {} at ({:.1}, {:.1}) mm: MISSED",
                t.kind,
                t.x_mm,
                t.y_mm
            ),
        }
    }
    say!(
        "against the truth: {} of {} defects found, {} reported that are not in the part",
        outcome.matches.iter().filter(|m| m.found.is_some()).count(),
        truth.len(),
        outcome.false_defects.len()
    );
    Ok(())
}

/// The extraction stage of the demo: every frame through the Steger estimator, scored against the truth.
fn extract_demo(out: &Path, sim_dir: &Path, frames: usize) -> Result<()> {
    use stripe3d_core::extract::{ExtractParams, Extraction, Extractor, Method};
    use stripe3d_sim::TruthPoint;
    use stripe3d_sim::evaluate::Score;
    let dir = out.join("extraction");
    prepare_dir(&dir)?;
    let params = ExtractParams {
        method: Method::Steger,
        ..ExtractParams::default()
    };
    let started = Instant::now();
    let results: Vec<Result<Extraction>> = (0..frames)
        .into_par_iter()
        .map_init(
            || Extractor::new(params.clone()),
            |ex, k| {
                let path = sim_dir.join(format!("frames/frame_{k:05}.png"));
                let frame = stripe3d_io::images::read_frame_native(&path, 64 << 20)?;
                let ex = ex.as_mut().map_err(|e| anyhow::anyhow!("{e}"))?;
                let mut e = Extraction::default();
                crate::extract::run_frame(ex, &frame, &mut e);
                Ok(e)
            },
        )
        .collect();
    let extractions: Vec<Extraction> = results.into_iter().collect::<Result<_>>()?;
    let seconds = started.elapsed().as_secs_f64();
    // Truth back from the simulation's CSV.
    let truth_text = read_text(&sim_dir.join("truth/stripes.csv"))?;
    let mut truth: Vec<Vec<TruthPoint>> = vec![Vec::new(); frames];
    for line in truth_text.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        let (Some(frame), Some(row), Some(u)) = (
            f.first().and_then(|v| v.parse::<usize>().ok()),
            f.get(1).and_then(|v| v.parse::<u32>().ok()),
            f.get(3).and_then(|v| v.parse::<f64>().ok()),
        ) else {
            continue;
        };
        if let Some(list) = truth.get_mut(frame) {
            list.push(TruthPoint {
                row,
                stripe: 0,
                u,
                world: [0.0; 3],
                part: [0.0; 3],
            });
        }
    }
    let mut score = Score::default();
    let mut csv = String::from("frame,row,x,intensity,width,score\n");
    for (k, e) in extractions.iter().enumerate() {
        let pts: Vec<(u32, f64)> = e.points.iter().map(|p| (p.row, p.x)).collect();
        score.add(&truth[k], &pts);
        for p in &e.points {
            csv.push_str(&format!(
                "{k},{},{:.5},{},{},{:.4}\n",
                p.row, p.x, p.intensity, p.width, p.score
            ));
        }
    }
    write_atomic(&dir.join("points.csv"), csv.as_bytes())?;
    say!(
        "extracted {} stripe points (Steger) in {:.0} ms: {:.2}% of the truth found within 0.5 px, RMS {:.3} px, {:.2}% false points",
        score.extracted,
        seconds * 1000.0,
        100.0 * score.detection_rate(),
        score.rms(),
        100.0 * score.false_rate()
    );
    say!("wrote {}", dir.join("points.csv").display());
    Ok(())
}
