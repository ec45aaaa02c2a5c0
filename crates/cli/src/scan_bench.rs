//! `stripe3d bench scans --scenes N --seed S --frames F`: whole scans of random simulator scenes
//! (`stripe3d_sim::random`, each with its own frame step), through the chain `stripe3d scan` runs (calibration from
//! rendered plates exposed for the plates, extraction, coding, reconciliation, spacetime analysis where the step allows, curvature
//! correction), each scan's points scored against the scene's true height map exactly as the validation set's scans
//! are (`stripe3d_io::validation::score_heights`: gross errors over 0.5 mm, RMS on smooth parts of the part,
//! coverage), and the distribution over scenes.

use crate::robustness_bench::quantile;
use anyhow::{Context, Result, bail};
use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;
use stripe3d_core::spacetime::Spacetime;
use stripe3d_io::validation::{HeightMap, HeightScore, score_profiles};
use stripe3d_sim::RenderOptions;
use stripe3d_sim::heightfield::HeightField;
use stripe3d_sim::pipeline::{calibrate_sensor, scan_scene_with};
use stripe3d_sim::random::RandomScene;

/// Worst scenes listed.
const WORST_LISTED: usize = 5;

/// One scene's outcome.
#[derive(Debug, Clone)]
pub struct ScanFigures {
    /// The scene seed.
    pub seed: u64,
    /// The draws in words, with the frame step.
    pub description: String,
    /// The points against the truth (`None`: the scene has no part to score).
    pub heights: Option<HeightScore>,
    /// Whether the frame step let the scan place points by their peak in time.
    pub spacetime: bool,
    /// Why the scene could not be scanned (its plates did not calibrate, nothing was measured), if so.
    pub failed: Option<String>,
    /// The scan's warnings about its input: on a scene drawn within the sensor's range, each is a false alarm.
    pub warnings: Vec<String>,
}

/// The simulator's true height field as a height map for the validation scoring.
fn height_map(field: &HeightField) -> Option<HeightMap> {
    let (cols, rows) = field.size();
    if cols < 2 || rows < 2 {
        return None;
    }
    let (x0, y0) = field.origin_mm();
    Some(HeightMap {
        origin_mm: [x0, y0],
        spacing_mm: field.spacing_mm(),
        cols,
        rows,
        z: field.heights().to_vec(),
    })
}

/// Draws scene `seed`, calibrates its sensor, scans `frames` frames of it and scores the points.
pub fn score_scan(seed: u64, frames: usize, spacetime: bool) -> Result<ScanFigures> {
    let mut scene = RandomScene::draw(seed);
    scene
        .expose()
        .with_context(|| format!("random scene {seed}"))?;
    let sensor = &scene.sensor;
    let step = sensor.conveyor.clone().unwrap_or_default().step_mm();
    let description = format!("{}; {step:.2} mm a frame", scene.describe());
    let failed = |why: String| ScanFigures {
        seed,
        description: description.clone(),
        heights: None,
        spacetime: false,
        failed: Some(why),
        warnings: Vec::new(),
    };
    // Calibrated as a user does: exposed for the plates. A sensor whose plates do not calibrate is a finding, not
    // the end of the bench.
    let calibration = scene
        .calibration_sensor()
        .with_context(|| format!("random scene {seed}"))?;
    let cal = match calibrate_sensor(&calibration, seed.wrapping_mul(7919)) {
        Ok(c) => c,
        // A refusal of the core's calibration says so itself.
        Err(stripe3d_sim::SimError::Sensor(e)) => return Ok(failed(e.to_string())),
        Err(e) => return Ok(failed(format!("calibration: {e}"))),
    };
    let spacetime = spacetime && Spacetime::for_scan(sensor, &cal.full, step).is_some();
    let opts = RenderOptions {
        seed,
        ..scene.opts.clone()
    };
    let grid = sensor.camera.belt_pixel_mm();
    let scan = scan_scene_with(
        sensor,
        &cal,
        &scene.scene,
        frames,
        opts,
        [grid, grid],
        true,
        spacetime,
    )
    .with_context(|| format!("scanning random scene {seed}"))?;
    let heights =
        height_map(scan.simulator.height_field()).map(|map| score_profiles(&map, &scan.profiles));
    Ok(ScanFigures {
        seed,
        description,
        heights,
        spacetime,
        failed: None,
        warnings: scan.warnings.iter().map(|w| w.to_string()).collect(),
    })
}

/// Runs `stripe3d bench scans`.
pub fn bench_scans(scenes: usize, seed: u64, frames: usize, spacetime: bool) -> Result<()> {
    if scenes == 0 {
        bail!("--scenes must be at least 1");
    }
    if frames < 2 {
        bail!("--frames must be at least 2: a scan moves the part between frames");
    }
    let bar = ProgressBar::new(scenes as u64);
    bar.set_style(
        ProgressStyle::with_template("{prefix} [{bar:30}] {pos}/{len} scenes, {eta} left")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.set_prefix("calibrating, rendering and scanning");
    let mut figures = (0..scenes as u64)
        .into_par_iter()
        .map(|i| {
            let r = score_scan(seed.wrapping_add(i), frames, spacetime);
            bar.inc(1);
            r
        })
        .collect::<Result<Vec<_>>>()?;
    bar.finish_and_clear();
    figures.sort_by_key(|f| f.seed);
    let scored: Vec<(&ScanFigures, &HeightScore)> = figures
        .iter()
        .filter_map(|f| f.heights.as_ref().map(|h| (f, h)))
        .filter(|(_, h)| h.points > 0)
        .collect();
    let gross: Vec<f64> = scored.iter().map(|(_, h)| h.gross_rate()).collect();
    let rms: Vec<f64> = scored
        .iter()
        .filter(|(_, h)| h.smooth_points > 0)
        .map(|(_, h)| h.rms_mm)
        .collect();
    let coverage: Vec<f64> = scored.iter().map(|(_, h)| h.coverage).collect();
    let with_time = figures.iter().filter(|f| f.spacetime).count();
    say!(
        "scans: {scenes} random scenes (seeds {seed} to {}) of {frames} frames, {} with a part to score, {with_time} \
         with a frame step fine enough for the spacetime analysis; points scored as the validation README says:",
        seed.wrapping_add(scenes as u64 - 1),
        scored.len()
    );
    say!("| figure | median | 5 % of scenes worse than | worst |");
    say!("|---|---:|---:|---:|");
    say!(
        "| gross errors (> 0.5 mm) | {:.4} | {:.4} | {:.4} |",
        quantile(&gross, 0.5),
        quantile(&gross, 0.95),
        quantile(&gross, 1.0)
    );
    say!(
        "| RMS on smooth parts, mm | {:.4} | {:.4} | {:.4} |",
        quantile(&rms, 0.5),
        quantile(&rms, 0.95),
        quantile(&rms, 1.0)
    );
    say!(
        "| coverage | {:.3} | {:.3} | {:.3} |",
        quantile(&coverage, 0.5),
        quantile(&coverage, 0.05),
        quantile(&coverage, 0.0)
    );
    let list = |title: &str, key: &dyn Fn(&HeightScore) -> f64| {
        let mut order = scored.clone();
        order.sort_by(|a, b| key(b.1).total_cmp(&key(a.1)));
        say!("{title}:");
        for (f, h) in order.iter().take(WORST_LISTED.min(order.len())) {
            say!(
                "  seed {}: gross {:.4} of {} points, RMS {:.4} mm, coverage {:.3}{}; {}",
                f.seed,
                h.gross_rate(),
                h.points,
                h.rms_mm,
                h.coverage,
                if f.spacetime { ", spacetime" } else { "" },
                f.description
            );
        }
    };
    let failures: Vec<&ScanFigures> = figures.iter().filter(|f| f.failed.is_some()).collect();
    if !failures.is_empty() {
        say!("not scanned ({}):", failures.len());
        for f in &failures {
            say!(
                "  seed {}: {}; {}",
                f.seed,
                f.failed.as_deref().unwrap_or_default(),
                f.description
            );
        }
    }
    let warned: Vec<&ScanFigures> = figures.iter().filter(|f| !f.warnings.is_empty()).collect();
    if !warned.is_empty() {
        say!("warned about their input ({}):", warned.len());
        for f in &warned {
            say!(
                "  seed {}: {}; {}",
                f.seed,
                f.warnings.join("; "),
                f.description
            );
        }
    }
    list("most gross errors", &|h| h.gross_rate());
    list("largest RMS", &|h| h.rms_mm);
    say!(
        "summary: scans over {} scenes ({} not scanned): gross errors median {:.4}, 95th percentile {:.4}; RMS median {:.4} mm, 95th \
         percentile {:.4} mm; coverage median {:.3}, 5th percentile {:.3}; {} warned about their input",
        scored.len(),
        failures.len(),
        quantile(&gross, 0.5),
        quantile(&gross, 0.95),
        quantile(&rms, 0.5),
        quantile(&rms, 0.95),
        quantile(&coverage, 0.5),
        quantile(&coverage, 0.05),
        warned.len()
    );
    Ok(())
}
