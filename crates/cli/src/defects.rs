//! `stripe3d bench defects`: simulated plates with random bumps, dents and holes, scanned through the whole chain
//! and inspected, scored against the simulator's defect truth; and clean plates that must come out clean.

use anyhow::{Context, Result, bail};
use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;
use std::path::Path;
use stripe3d_core::Sensor;
use stripe3d_core::accumulate::RangeImage;
use stripe3d_core::calibrate::Calibration;
use stripe3d_core::characterize::{
    CharacterizeParams, PreparedGolden, ReferenceShape, ReferenceSource,
};
use stripe3d_core::detect::{Defect, DetectParams, SurfaceRules, inspect};
use stripe3d_sim::batch::{Match, PartOutcome, match_defects};
use stripe3d_sim::pipeline::{calibrate_sensor, frames_for_sweep, scan_scene_with};
use stripe3d_sim::{DefectTruth, RenderOptions, Scene};

/// `--golden`: the golden plate's render seed is the bench's seed plus this (no part shares it).
const GOLDEN_SEED_OFFSET: u64 = 2_000_000;

/// Targets of the defect-detection issue.
const TARGET_RECALL: f64 = 0.99;
const TARGET_PRECISION: f64 = 0.99;
const TARGET_KIND: f64 = 0.98;
const TARGET_CENTROID_MM: f64 = 0.5;
const TARGET_AREA: f64 = 0.15;
const TARGET_DEPTH_MM: f64 = 0.03;

/// Inspects a range image of a plate scanned with `travel_step_mm` between frames against a fitted plane (or the
/// `golden` scan of a clean plate, prepared once for all plates) with the shipped rules and
/// default parameters.
pub fn inspect_plate(
    range: &RangeImage,
    travel_step_mm: f64,
    golden: Option<&PreparedGolden>,
) -> Result<(Vec<Defect>, Vec<String>)> {
    let mut rules = SurfaceRules::shipped()?;
    let i = inspect(
        range,
        golden.map_or(
            ReferenceSource::Fit(ReferenceShape::Plane),
            ReferenceSource::Prepared,
        ),
        &CharacterizeParams::default(),
        &mut rules,
        &DetectParams {
            travel_step_mm: Some(travel_step_mm),
            ..DetectParams::default()
        },
    )?;
    Ok((i.detection.defects, i.detection.warnings))
}

/// What every plate of the benchmark goes through: the simulated sensor, its calibration, the scan's frames and grid,
/// and the reference.
struct Chain<'a> {
    sensor: &'a Sensor,
    cal: &'a Calibration,
    frames: usize,
    grid: [f64; 2],
    curvature_correction: bool,
    golden: Option<&'a PreparedGolden>,
}

fn scan_and_inspect(chain: &Chain<'_>, scene: &Scene, seed: u64) -> Result<PartOutcome> {
    let opts = RenderOptions {
        seed,
        ..RenderOptions::default()
    };
    let scan = scan_scene_with(
        chain.sensor,
        chain.cal,
        scene,
        chain.frames,
        opts,
        chain.grid,
        chain.curvature_correction,
        true,
    )
    .with_context(|| format!("scanning {}", scene.name))?;
    // The step of the conveyor `scan_scene` moves the part with.
    let step = chain.sensor.conveyor.clone().unwrap_or_default().step_mm();
    let (found, warnings) = inspect_plate(&scan.range, step, chain.golden)
        .with_context(|| format!("inspecting {}", scene.name))?;
    let mut out = match_defects(scan.simulator.defects(), &found);
    out.warnings = warnings;
    Ok(out)
}

/// Columns of `bench defects --csv`: one line per true defect (the found columns empty when it was missed) and one
/// per false defect (the truth columns empty).
const CSV_HEADER: &str = "plate,seed,truth_kind,truth_x_mm,truth_y_mm,truth_diameter_mm,truth_area_mm2,\
truth_depth_mm,found_kind,found_x_mm,found_y_mm,found_area_mm2,found_depth_mm,confidence,centroid_err_mm,\
area_err_pct,depth_err_mm";

/// The CSV lines of one plate's outcome.
fn csv_rows(plate: &str, seed: u64, o: &PartOutcome) -> Vec<String> {
    let truth = |t: &DefectTruth| {
        format!(
            "{},{:.4},{:.4},{:.4},{:.4},{:.4}",
            t.kind, t.x_mm, t.y_mm, t.diameter_mm, t.area_mm2, t.depth_mm
        )
    };
    let found = |f: &Defect| {
        format!(
            "{},{:.4},{:.4},{:.4},{:.4},{:.3}",
            f.kind.name(),
            f.centroid_mm[0],
            f.centroid_mm[1],
            f.area_mm2,
            f.depth_mm,
            f.confidence
        )
    };
    let mut rows = Vec::new();
    for m in &o.matches {
        let t = &m.truth;
        let rest = match &m.found {
            Some(f) => format!(
                "{},{:.4},{:.2},{:.4}",
                found(f),
                (f.centroid_mm[0] - t.x_mm).hypot(f.centroid_mm[1] - t.y_mm),
                100.0 * (f.area_mm2 - t.area_mm2) / t.area_mm2,
                f.depth_mm - t.depth_mm
            ),
            None => ",,,,,,,,".to_string(),
        };
        rows.push(format!("{plate},{seed},{},{rest}", truth(t)));
    }
    for f in &o.false_defects {
        rows.push(format!("{plate},{seed},,,,,,,{},,,", found(f)));
    }
    rows
}

fn pct(a: usize, b: usize) -> f64 {
    100.0 * a as f64 / b.max(1) as f64
}

/// The `p` quantile (0 to 1) of a list, nearest rank (sorts it); NaN when empty.
pub fn percentile(v: &mut [f64], p: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * p).round() as usize]
}

/// What `stripe3d bench defects` is asked for.
pub struct DefectBench<'a> {
    /// Plates with defects.
    pub parts: usize,
    /// Clean plates.
    pub clean: usize,
    /// Defects per defective plate.
    pub per_part: usize,
    /// Seed of the random parts and renders.
    pub seed: u64,
    /// List every miss, wrong kind, out-of-tolerance measurement and false defect.
    pub verbose: bool,
    /// Correct the heights for the sheets' curvature bias.
    pub curvature_correction: bool,
    /// Also write the CSV of every defect here.
    pub csv: Option<&'a Path>,
    /// Inspect against a golden scan of a clean plate instead of a fitted plane.
    pub golden: bool,
}

/// Runs `stripe3d bench defects`.
pub fn bench_defects(b: &DefectBench<'_>) -> Result<()> {
    let DefectBench {
        parts,
        clean,
        per_part,
        seed,
        verbose,
        curvature_correction,
        csv,
        golden,
    } = *b;
    if parts == 0 && clean == 0 {
        bail!("--parts 0 --clean 0: nothing to measure");
    }
    if let Some(path) = csv {
        // Checked before minutes of scanning, not after.
        let dir = path
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        if !dir.is_dir() {
            bail!(
                "--csv {}: folder {} does not exist; create it or write the table elsewhere",
                path.display(),
                dir.display()
            );
        }
        if path.is_dir() {
            bail!("--csv {}: is a folder; give a file name", path.display());
        }
    }
    if per_part == 0 || per_part > 12 {
        bail!(
            "--defects {per_part}: give 1 to 12 defects per part (they must fit 3 mm apart on an 80 x 60 mm plate)"
        );
    }
    let sensor = Sensor::default();
    say!("calibrating the simulated sensor (plates at 0-35 mm) ...");
    let cal = calibrate_sensor(&sensor, seed.wrapping_add(10_000))?;
    let frames = frames_for_sweep(&sensor, 2);
    let grid = crate::scan::default_grid(&sensor);
    // The golden scan: a clean plate, rendered with a seed of its own, scanned as the parts are.
    let golden_seed = seed.wrapping_add(GOLDEN_SEED_OFFSET);
    let golden_range = if golden {
        say!("scanning the golden plate (render seed {golden_seed}) ...");
        let opts = RenderOptions {
            seed: golden_seed,
            ..RenderOptions::default()
        };
        let scan = scan_scene_with(
            &sensor,
            &cal,
            &Scene::flat_plate(),
            frames,
            opts,
            grid,
            curvature_correction,
            true,
        )
        .context("scanning the golden plate")?;
        // Cleaned and its wall spans mapped once for every plate, with the inspection's own parameters.
        let step = sensor.conveyor.clone().unwrap_or_default().step_mm();
        Some(PreparedGolden::new(
            &scan.range,
            DetectParams::default().outlier_mm,
            CharacterizeParams::default().belt_level_mm,
            Some(step),
        ))
    } else {
        None
    };
    let chain = Chain {
        sensor: &sensor,
        cal: &cal,
        frames,
        grid,
        curvature_correction,
        golden: golden_range.as_ref(),
    };
    let jobs: Vec<(bool, u64)> = (0..parts as u64)
        .map(|i| (true, seed.wrapping_add(i)))
        .chain((0..clean as u64).map(|i| (false, seed.wrapping_add(1_000_000 + i))))
        .collect();
    let bar = ProgressBar::new(jobs.len() as u64).with_style(
        ProgressStyle::with_template("{msg} [{bar:40}] {pos}/{len} parts ({eta})")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar.set_message(format!("scanning and inspecting ({frames} frames a part)"));
    let started = std::time::Instant::now();
    let outcomes: Vec<Result<(bool, String, u64, PartOutcome)>> = jobs
        .par_iter()
        .map(|&(defective, s)| {
            let scene = if defective {
                Scene::defect_plate(s, per_part)
            } else {
                Scene::flat_plate()
            };
            let r =
                scan_and_inspect(&chain, &scene, s).map(|o| (defective, scene.name.clone(), s, o));
            bar.inc(1);
            r
        })
        .collect();
    bar.finish_and_clear();
    let seconds = started.elapsed().as_secs_f64();
    let mut all: Vec<(bool, String, PartOutcome)> = Vec::new();
    let mut rows = Vec::new();
    for o in outcomes {
        let (defective, scene, s, outcome) = o?;
        rows.extend(csv_rows(&scene, s, &outcome));
        all.push((defective, format!("{scene} (render seed {s})"), outcome));
    }
    if let Some(path) = csv {
        let mut text = String::from(CSV_HEADER);
        text.push('\n');
        for r in &rows {
            text.push_str(r);
            text.push('\n');
        }
        stripe3d_io::files::write_atomic(path, text.as_bytes())
            .with_context(|| format!("writing --csv {}", path.display()))?;
    }
    // Figures.
    let matches: Vec<&Match> = all
        .iter()
        .filter(|a| a.0)
        .flat_map(|a| &a.2.matches)
        .collect();
    let found_on_defective: usize = all
        .iter()
        .filter(|a| a.0)
        .map(|a| a.2.matches.iter().filter(|m| m.found.is_some()).count() + a.2.false_defects.len())
        .sum();
    let false_on_defective: usize = all
        .iter()
        .filter(|a| a.0)
        .map(|a| a.2.false_defects.len())
        .sum();
    let hit: Vec<(&DefectTruth, &Defect)> = matches
        .iter()
        .filter_map(|m| m.found.as_ref().map(|f| (&m.truth, f)))
        .collect();
    let kind_ok = hit.iter().filter(|(t, f)| f.kind.name() == t.kind).count();
    let centroid: Vec<f64> = hit
        .iter()
        .map(|(t, f)| (f.centroid_mm[0] - t.x_mm).hypot(f.centroid_mm[1] - t.y_mm))
        .collect();
    let area: Vec<f64> = hit
        .iter()
        .map(|(t, f)| (f.area_mm2 - t.area_mm2) / t.area_mm2)
        .collect();
    let depth: Vec<f64> = hit.iter().map(|(t, f)| f.depth_mm - t.depth_mm).collect();
    let clean_runs: Vec<&(bool, String, PartOutcome)> = all.iter().filter(|a| !a.0).collect();
    let clean_false: usize = clean_runs.iter().map(|a| a.2.false_defects.len()).sum();
    let clean_rejected = clean_runs
        .iter()
        .filter(|a| !a.2.false_defects.is_empty())
        .count();
    let within = |v: &[f64], lim: f64| v.iter().filter(|e| e.abs() <= lim).count();
    let verdict = |ok: bool| if ok { "met" } else { "NOT met" };
    say!(
        "\n{} defective plates ({} defects each, {} in all) and {} clean plates, {} frames each, scanned and inspected in \
         {seconds:.0} s on {} threads (curvature correction {}; reference: {})\n",
        parts,
        per_part,
        matches.len(),
        clean,
        frames,
        rayon::current_num_threads(),
        if curvature_correction { "on" } else { "off" },
        if golden {
            format!("golden scan of a clean plate, render seed {golden_seed}")
        } else {
            "fitted plane".to_string()
        }
    );
    say!("| figure | measured | target | |");
    say!("|---|---|---|---|");
    let recall = hit.len() as f64 / matches.len().max(1) as f64;
    let precision = hit.len() as f64 / found_on_defective.max(1) as f64;
    let kind = kind_ok as f64 / hit.len().max(1) as f64;
    say!(
        "| recall | {:.2}% ({} of {}) | >= 99% | {} |",
        100.0 * recall,
        hit.len(),
        matches.len(),
        verdict(recall >= TARGET_RECALL)
    );
    say!(
        "| precision | {:.2}% ({} false of {} reported) | >= 99% | {} |",
        100.0 * precision,
        false_on_defective,
        found_on_defective,
        verdict(precision >= TARGET_PRECISION)
    );
    say!(
        "| kind correct | {:.2}% ({} of {}) | >= 98% | {} |",
        100.0 * kind,
        kind_ok,
        hit.len(),
        verdict(kind >= TARGET_KIND)
    );
    let (mut c, mut a, mut d) = (
        centroid.clone(),
        area.iter().map(|v| v.abs()).collect::<Vec<_>>(),
        depth.iter().map(|v| v.abs()).collect::<Vec<_>>(),
    );
    let c_ok = within(&centroid, TARGET_CENTROID_MM);
    say!(
        "| centroid within 0.5 mm | {:.2}% (median {:.3} mm, 95% {:.3}, max {:.3}) | all | {} |",
        pct(c_ok, hit.len()),
        percentile(&mut c, 0.5),
        percentile(&mut c, 0.95),
        percentile(&mut c, 1.0),
        verdict(c_ok == hit.len())
    );
    let a_ok = within(&area, TARGET_AREA);
    say!(
        "| area within 15% | {:.2}% (median {:.1}%, 95% {:.1}%, max {:.1}%) | all | {} |",
        pct(a_ok, hit.len()),
        100.0 * percentile(&mut a, 0.5),
        100.0 * percentile(&mut a, 0.95),
        100.0 * percentile(&mut a, 1.0),
        verdict(a_ok == hit.len())
    );
    let d_ok = within(&depth, TARGET_DEPTH_MM);
    say!(
        "| depth within 0.03 mm | {:.2}% (median {:.4} mm, 95% {:.4}, max {:.4}) | all | {} |",
        pct(d_ok, hit.len()),
        percentile(&mut d, 0.5),
        percentile(&mut d, 0.95),
        percentile(&mut d, 1.0),
        verdict(d_ok == hit.len())
    );
    say!(
        "| false defects on clean plates | {clean_false} on {clean_rejected} of {} plates | 0 | {} |",
        clean_runs.len(),
        verdict(clean_false == 0)
    );
    say!(
        "\n| kind | truth | found | kind right | centroid err median (mm) | area err median | depth err median (mm) |"
    );
    say!("|---|---:|---:|---:|---:|---:|---:|");
    for k in ["bump", "dent", "hole"] {
        let ms: Vec<&&Match> = matches.iter().filter(|m| m.truth.kind == k).collect();
        let hs: Vec<(&DefectTruth, &Defect)> = ms
            .iter()
            .filter_map(|m| m.found.as_ref().map(|f| (&m.truth, f)))
            .collect();
        let mut ce: Vec<f64> = hs
            .iter()
            .map(|(t, f)| (f.centroid_mm[0] - t.x_mm).hypot(f.centroid_mm[1] - t.y_mm))
            .collect();
        let mut ae: Vec<f64> = hs
            .iter()
            .map(|(t, f)| ((f.area_mm2 - t.area_mm2) / t.area_mm2).abs())
            .collect();
        let mut de: Vec<f64> = hs
            .iter()
            .map(|(t, f)| (f.depth_mm - t.depth_mm).abs())
            .collect();
        say!(
            "| {k} | {} | {} | {} | {:.3} | {:.1}% | {:.4} |",
            ms.len(),
            hs.len(),
            hs.iter().filter(|(t, f)| f.kind.name() == t.kind).count(),
            percentile(&mut ce, 0.5),
            100.0 * percentile(&mut ae, 0.5),
            percentile(&mut de, 0.5)
        );
    }
    if verbose {
        say!("\nmisses, wrong kinds, out-of-tolerance measurements and false defects:");
        for (_, name, o) in &all {
            for m in &o.matches {
                let t = &m.truth;
                let line = match &m.found {
                    None => Some("MISSED".to_string()),
                    Some(f) => {
                        let ce = (f.centroid_mm[0] - t.x_mm).hypot(f.centroid_mm[1] - t.y_mm);
                        let ae = (f.area_mm2 - t.area_mm2) / t.area_mm2;
                        let de = f.depth_mm - t.depth_mm;
                        (f.kind.name() != t.kind || ce > TARGET_CENTROID_MM || ae.abs() > TARGET_AREA || de.abs() > TARGET_DEPTH_MM)
                            .then(|| format!(
                                "found {} ({:.2}) centroid err {ce:.3} mm, area {:.2} mm² ({:+.1}%), depth {:.3} mm ({de:+.4}); evidence {:?}",
                                f.kind.name(), f.confidence, f.area_mm2, 100.0 * ae, f.depth_mm, f.evidence
                            ))
                    }
                };
                if let Some(l) = line {
                    say!(
                        "  {name}: {} d={:.2} mm depth {:.3} mm at ({:.1}, {:.1}): {l}",
                        t.kind,
                        t.diameter_mm,
                        t.depth_mm,
                        t.x_mm,
                        t.y_mm
                    );
                }
            }
            for f in &o.false_defects {
                say!(
                    "  {name}: FALSE {} ({:.2}) at ({:.1}, {:.1}) area {:.2} mm² depth {:.3} mm; evidence {:?}",
                    f.kind.name(),
                    f.confidence,
                    f.centroid_mm[0],
                    f.centroid_mm[1],
                    f.area_mm2,
                    f.depth_mm,
                    f.evidence
                );
            }
            for w in &o.warnings {
                say!("  {name}: warning: {w}");
            }
        }
    }
    Ok(())
}
