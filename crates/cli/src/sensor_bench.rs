//! `stripe3d bench sensor`: the paper's performance table (section 5), reproduced on the simulated set-up and set
//! side by side with the paper's figures.

use anyhow::{Context, Result};
use std::time::Instant;
use stripe3d_core::Sensor;
use stripe3d_core::code::CodedFrame;
use stripe3d_core::curvature::CurvatureBias;
use stripe3d_core::scan::{profiles_of, range_image_corrected};
use stripe3d_sim::pipeline::{calibrate_sensor, frames_for_sweep, scanner};
use stripe3d_sim::{Frame, RenderOptions, Scene, Simulator};

/// Runs `stripe3d bench sensor`.
pub fn bench_sensor(repeats: usize) -> Result<()> {
    let sensor = Sensor::default();
    let repeats = repeats.clamp(1, 100);
    say!("calibrating the simulated paper set-up (plates at 0-35 mm) ...");
    let cal = calibrate_sensor(&sensor, 77)?;
    let conveyor = sensor.conveyor.clone().unwrap_or_default();
    let step = conveyor.speed_mm_s / conveyor.fps;
    let frames = frames_for_sweep(&sensor, 2);
    // A plate larger than the view, 10 mm thick: every stripe on it in every frame.
    let plate_z = 10.0;
    let sim = Simulator::new(
        &sensor,
        &Scene::covering_plate(plate_z),
        RenderOptions::default(),
    )?;
    let rendered: Vec<Frame> = (0..frames)
        .map(|k| sim.render(k, conveyor.travel_mm(k)))
        .collect();
    let hi = cal.coding_range_mm().1;
    let grid = crate::scan::default_grid(&sensor);
    let mut scanner = scanner(&cal)?;
    // The curvature-bias correction `stripe3d scan` applies by default (it changes nothing on a flat plate but
    // its time counts).
    let bias = CurvatureBias::new(
        &sensor,
        &cal.full,
        stripe3d_sim::pipeline::extract_params().method,
    );
    // Processing time of one depth image (every frame of one sweep: extraction to range image), one core.
    let mut times = Vec::new();
    let mut range = None;
    let travel: Vec<f64> = (0..rendered.len()).map(|k| conveyor.travel_mm(k)).collect();
    // One core: the parts of the chain that run in parallel (reconciliation, triangulation, accumulation) run on a
    // pool of one thread here.
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .context("a one-thread pool for the timing")?;
    for _ in 0..repeats {
        let t = Instant::now();
        // As `stripe3d scan` does: extract and code every frame, reconcile across frames, triangulate, accumulate.
        let r = one.install(|| {
            let mut coded: Vec<CodedFrame> = rendered
                .iter()
                .map(|f| {
                    let mut c = CodedFrame::default();
                    scanner.code_into(f.image.view(), &mut c);
                    c
                })
                .collect();
            let mut profiles = profiles_of(&mut coded, &travel, &cal, scanner.model()).0;
            range_image_corrected(&mut profiles, grid, bias.as_ref())
        })?;
        range = Some(r.0);
        times.push(t.elapsed().as_secs_f64());
    }
    let seconds = crate::defects::percentile(&mut times, 0.5);
    let Some(range) = range else {
        anyhow::bail!("no depth image was made");
    };
    // Depth resolution, noise-limited: spread of the measured heights of the flat plate.
    let cell = range.spacing_mm[0] * range.spacing_mm[1];
    let errs: Vec<f64> = range
        .z
        .iter()
        .filter(|z| z.is_finite() && (f64::from(**z) - plate_z).abs() < 1.0)
        .map(|z| f64::from(*z) - plate_z)
        .collect();
    let n = errs.len().max(1) as f64;
    let mean = errs.iter().sum::<f64>() / n;
    let sigma = (errs.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / n).sqrt();
    let scanned_cm2 = errs.len() as f64 * cell / 100.0;
    // Geometric depth resolution: height change that moves the centre stripe one pixel, at the centre row.
    let (w, h) = (sensor.camera.width as f64, sensor.camera.height as f64);
    let mid = sensor.laser.stripes / 2;
    let per_px = |z: f64| {
        let a = cal.full.column_at_height(mid, h / 2.0, z)?;
        let b = cal.full.column_at_height(mid, h / 2.0, z + 1.0)?;
        Some(1.0 / (b - a).abs())
    };
    let mm_per_px = per_px(0.0).unwrap_or(f64::NAN);
    // Depth range: heights at which the centre stripe stays in the image at the centre row (and any stripe).
    let in_view = |s: usize, z: f64| {
        cal.full
            .column_at_height(s, h / 2.0, z)
            .is_some_and(|u| (0.0..=w - 1.0).contains(&u))
    };
    let mut z_max = 0.0;
    let mut z_any = 0.0;
    let mut z = 0.0;
    while z < sensor.camera.height_mm - 1.0 {
        if in_view(mid, z) {
            z_max = z;
        }
        if (0..sensor.laser.stripes).any(|s| in_view(s, z)) {
            z_any = z;
        }
        z += 0.5;
    }
    // The smallest step told apart from noise at 3 sigma of a difference of two surfaces.
    let min_step = 3.0 * std::f64::consts::SQRT_2 * sigma;
    // Width seen across the belt: the image's rows on the belt.
    let width_cm = sensor.camera.height as f64 * sensor.camera.belt_pixel_mm() / 10.0;
    let rate_conveyor = conveyor.speed_mm_s / 10.0 * width_cm;
    let frames_per_s = frames as f64 / seconds;
    let rate_processing = scanned_cm2 / seconds;
    say!(
        "\nThe paper's set-up, simulated: 648x480 camera 100 mm above the belt, 11 stripes {} mm apart, conveyor {} mm/s \
         at {} frames/s ({step} mm per frame); one depth image = {frames} frames (one stripe pitch of travel and two \
         more), one core.\n",
        sensor.laser.pitch_mm,
        conveyor.speed_mm_s,
        conveyor.fps
    );
    say!("| figure | paper | stripe3d (measured) | how |");
    say!("|---|---|---|---|");
    say!(
        "| lateral resolution | 1.696 ± 0.02 mm | {step:.3} mm along travel, {:.3} mm across | travel per frame (speed / fps); one image row on the belt |",
        sensor.camera.belt_pixel_mm()
    );
    say!(
        "| depth resolution | 0.22 mm | {sigma:.4} mm (noise, 1 sigma); {mm_per_px:.3} mm per pixel of stripe shift | spread of a flat 10 mm plate's range image about its mean (mean error {mean:+.4} mm); the geometry's height per pixel at the centre |"
    );
    say!(
        "| depth range | 0.44 mm to 7 cm | {min_step:.3} mm to {:.1} cm (centre stripe in view), {:.1} cm (any stripe); calibrated {:.1}-{:.1} cm, coded up to {:.2} cm | smallest step 3·√2·sigma; highest height at which the stripe stays in the image; the calibration's plates and the coding range |",
        z_max / 10.0,
        z_any / 10.0,
        cal.fitted_range_mm().0 / 10.0,
        cal.fitted_range_mm().1 / 10.0,
        hi / 10.0
    );
    say!(
        "| scanned area | 87.24 ± 1.01 cm² | {scanned_cm2:.1} cm² | measured cells of one depth image of a plate covering the view |"
    );
    say!(
        "| profiling rate | 4 cm²/s | {rate_conveyor:.1} cm²/s at the paper's 1 cm/s; {rate_processing:.0} cm²/s processing-limited | belt speed x width seen; area of one depth image / its processing time |"
    );
    say!(
        "| time per 11-stripe depth image | <= 4 s (400 MHz PC) | {:.1} ms ({frames_per_s:.0} frames/s) | extraction (Steger), coding, temporal reconciliation, triangulation, accumulation of {frames} frames with the curvature-bias correction, median of {repeats}, one core |",
        seconds * 1000.0
    );
    Ok(())
}
