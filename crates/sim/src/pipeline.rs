//! The measuring chain on simulated frames, in memory: a calibration fitted from rendered plate images, and scans
//! of a scene through [`stripe3d_core::scan::Scanner`] — the same code `stripe3d calibrate` and `stripe3d scan`
//! run, without files in between. Benchmarks and ground-truth tests use it.

use crate::{RenderOptions, Scene, SimError, Simulator};
use stripe3d_core::Sensor;
use stripe3d_core::accumulate::{ModelKind, Profile, RangeImage};
use stripe3d_core::calibrate::{Calibration, CalibrationParams, PlaneImage, calibrate};
use stripe3d_core::code::{CodedFrame, CodingParams};
use stripe3d_core::extract::{ExtractParams, Extraction, Extractor, Method};
use stripe3d_core::image::Image;
use stripe3d_core::scan::{ScanOptions, Scanner, finish_scan, spacetime_for};

/// Plate heights of the simulated calibration, mm: every stripe of the paper's set-up is seen at three of them.
pub const CALIBRATION_HEIGHTS_MM: [f64; 6] = [0.0, 5.0, 10.0, 20.0, 30.0, 35.0];

/// The extraction every simulated scan uses: Steger's detector, the most accurate (`stripe3d bench accuracy`).
pub fn extract_params() -> ExtractParams {
    ExtractParams {
        method: Method::Steger,
        ..ExtractParams::default()
    }
}

/// Calibrates `sensor` from rendered plate images at [`CALIBRATION_HEIGHTS_MM`] (the empty belt for 0).
pub fn calibrate_sensor(sensor: &Sensor, seed: u64) -> Result<Calibration, SimError> {
    let mut ex = Extractor::new(extract_params())?;
    let mut images = Vec::new();
    for (i, &z) in CALIBRATION_HEIGHTS_MM.iter().enumerate() {
        let scene = if z == 0.0 {
            Scene::empty_belt()
        } else {
            Scene::covering_plate(z)
        };
        let opts = RenderOptions {
            seed: seed.wrapping_add(i as u64),
            ..RenderOptions::default()
        };
        let frame = Simulator::new(sensor, &scene, opts)?.render(0, 0.0);
        let mut e = Extraction::default();
        ex.extract_into(frame.image.view(), &mut e);
        images.push(PlaneImage {
            name: format!("plate at {z} mm"),
            height_mm: z,
            points: e.points,
        });
    }
    Ok(calibrate(sensor, &images, &CalibrationParams::default())?)
}

/// The scanner every simulated scan uses: Steger extraction, the full model, and the heights stripe coding allows
/// by default for this calibration (as `stripe3d scan` does).
pub fn scanner(cal: &Calibration) -> Result<Scanner, SimError> {
    let (lo, hi) = cal.coding_range_mm();
    let coding = CodingParams {
        min_height_mm: lo,
        max_height_mm: hi,
        ..CodingParams::default()
    };
    Ok(Scanner::new(
        cal,
        extract_params(),
        coding,
        ModelKind::Full,
    )?)
}

/// Frames a scan needs so that every stripe sweeps one stripe pitch plus `extra` frames (the bands of
/// neighbouring stripes then overlap and the range image has no empty seams).
pub fn frames_for_sweep(sensor: &Sensor, extra: usize) -> usize {
    let conveyor = sensor.conveyor.clone().unwrap_or_default();
    let step = conveyor.speed_mm_s / conveyor.fps;
    if step > 0.0 {
        (sensor.laser.pitch_mm / step).ceil() as usize + extra
    } else {
        1
    }
}

/// One simulated scan: its profiles, range image and the simulator (for the truth).
pub struct SimulatedScan {
    /// Triangulated profiles in frame order.
    pub profiles: Vec<Profile>,
    /// The range image on the requested grid.
    pub range: RangeImage,
    /// The simulator that rendered the frames (true height field and defects).
    pub simulator: Simulator,
    /// What the scan found doubtful about its input (see [`stripe3d_core::scan::ScanWarning`]).
    pub warnings: Vec<stripe3d_core::scan::ScanWarning>,
}

/// Renders `frames` frames of `scene` (travel from the sensor's conveyor), and scans them with the full model on a
/// grid of `grid_mm`; coding allows the calibrated heights widened as `stripe3d scan` does by default, and the
/// heights are corrected for the sheets' curvature bias as `stripe3d scan` does by default.
pub fn scan_scene(
    sensor: &Sensor,
    cal: &Calibration,
    scene: &Scene,
    frames: usize,
    opts: RenderOptions,
    grid_mm: [f64; 2],
) -> Result<SimulatedScan, SimError> {
    scan_scene_with(sensor, cal, scene, frames, opts, grid_mm, true, true)
}

/// [`scan_scene`], with the curvature-bias correction on or off, and the spacetime analysis on (where the frame step
/// allows it, as `stripe3d scan` does by default) or off.
#[allow(clippy::too_many_arguments)]
pub fn scan_scene_with(
    sensor: &Sensor,
    cal: &Calibration,
    scene: &Scene,
    frames: usize,
    opts: RenderOptions,
    grid_mm: [f64; 2],
    curvature_correction: bool,
    spacetime: bool,
) -> Result<SimulatedScan, SimError> {
    let simulator = Simulator::new(sensor, scene, opts)?;
    let mut scanner = scanner(cal)?;
    let conveyor = sensor.conveyor.clone().unwrap_or_default();
    let travel: Vec<f64> = (0..frames).map(|k| conveyor.travel_mm(k)).collect();
    let options = ScanOptions {
        grid_mm,
        curvature_correction,
        spacetime,
    };
    let keep_frames = spacetime_for(sensor, cal, &travel, &options).is_some();
    let mut coded = Vec::with_capacity(frames);
    let mut images: Vec<Image<u16>> = Vec::new();
    for (k, &t) in travel.iter().enumerate() {
        let frame = simulator.render(k, t);
        let mut c = CodedFrame::default();
        scanner.code_into(frame.image.view(), &mut c);
        coded.push(c);
        if keep_frames {
            images.push(frame.image);
        }
    }
    let scan = finish_scan(
        &mut coded,
        &images,
        &travel,
        sensor,
        cal,
        scanner.model(),
        extract_params().method,
        &options,
    )?;
    Ok(SimulatedScan {
        profiles: scan.profiles,
        range: scan.range,
        simulator,
        warnings: scan.warnings,
    })
}
