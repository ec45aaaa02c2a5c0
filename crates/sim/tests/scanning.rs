//! The whole chain from frames to millimetres (extraction, coding, triangulation with a calibration fitted from
//! simulated plate images, accumulation), measured against the simulator's true height map.

use stripe3d_core::accumulate::{ModelKind, Profile, RangeGrid, RangeParams, profile_into};
use stripe3d_core::calibrate::{Calibration, CalibrationParams, PlaneImage, calibrate};
use stripe3d_core::code::{Coding, CodingParams, StripeCoder};
use stripe3d_core::extract::{ExtractParams, Extraction, Extractor, Method};
use stripe3d_core::scan::refine_in_time;
use stripe3d_core::spacetime::Spacetime;
use stripe3d_core::{Image, Sensor};
use stripe3d_sim::scene::Feature;
use stripe3d_sim::{Frame, RenderOptions, Scene, Simulator};

fn to_u8(f: &Frame) -> Image<u8> {
    let data: Vec<u8> = f.image.data().iter().map(|&v| v.min(255) as u8).collect();
    Image::from_vec(f.image.width(), f.image.height(), data).expect("image")
}

fn extractor() -> Extractor {
    Extractor::new(ExtractParams {
        method: Method::Steger,
        ..ExtractParams::default()
    })
    .expect("extractor")
}

fn calibration(sensor: &Sensor) -> Calibration {
    let mut ex = extractor();
    let images: Vec<PlaneImage> = [0.0, 5.0, 10.0, 20.0, 30.0, 35.0]
        .iter()
        .enumerate()
        .map(|(i, &z)| {
            let scene = if z == 0.0 {
                Scene::empty_belt()
            } else {
                Scene::covering_plate(z)
            };
            let opts = RenderOptions {
                seed: 100 + i as u64,
                ..RenderOptions::default()
            };
            let f = Simulator::new(sensor, &scene, opts)
                .expect("sim")
                .render(0, 0.0);
            let mut e = Extraction::default();
            ex.extract_into(to_u8(&f).view(), &mut e);
            PlaneImage {
                name: format!("{z} mm"),
                height_mm: z,
                points: e.points,
            }
        })
        .collect();
    calibrate(sensor, &images, &CalibrationParams::default()).expect("calibration")
}

/// Profiles of `frames` frames of `scene`, 0.5 mm apart.
fn scan(
    sensor: &Sensor,
    cal: &Calibration,
    scene: &Scene,
    frames: usize,
    kind: ModelKind,
) -> (Vec<Profile>, Simulator) {
    let (profiles, _, _, sim) = scan_every(sensor, cal, scene, frames, 0.5, kind);
    (profiles, sim)
}

/// Profiles of `frames` frames of `scene`, `step_mm` apart, with the frames and their travel.
fn scan_every(
    sensor: &Sensor,
    cal: &Calibration,
    scene: &Scene,
    frames: usize,
    step_mm: f64,
    kind: ModelKind,
) -> (Vec<Profile>, Vec<Image<u8>>, Vec<f64>, Simulator) {
    let sim = Simulator::new(sensor, scene, RenderOptions::default()).expect("sim");
    let mut coder = StripeCoder::new(
        &cal.full,
        sensor.camera.width,
        sensor.camera.height,
        CodingParams {
            min_height_mm: -1.0,
            max_height_mm: 40.0,
            ..CodingParams::default()
        },
    )
    .expect("coder");
    let mut ex = extractor();
    let (mut e, mut c) = (Extraction::default(), Coding::default());
    let (mut out, mut images, mut travels) = (Vec::new(), Vec::new(), Vec::new());
    for k in 0..frames {
        let travel = step_mm * k as f64;
        let image = to_u8(&sim.render(k, travel));
        ex.extract_into(image.view(), &mut e);
        coder.code_into(&e.points, &mut c);
        let mut p = Profile::default();
        profile_into(
            k,
            travel,
            &e.points,
            &c,
            &cal.full,
            Some(&cal.linear),
            kind,
            &mut p,
        );
        out.push(p);
        images.push(image);
        travels.push(travel);
    }
    (out, images, travels, sim)
}

/// Height errors of the points whose true surface is smooth within `r` mm (no edge to smear), and whose true
/// height is above `min_z` (the part, not the belt).
fn errors(profiles: &[Profile], sim: &Simulator, r: f64, min_z: f64) -> Vec<f64> {
    let hf = sim.height_field();
    let mut out = Vec::new();
    for p in profiles.iter().flat_map(|p| &p.points) {
        let z0 = hf.height_at(p.x_mm, p.y_mm);
        if z0 < min_z {
            continue;
        }
        let smooth = [(-r, 0.0), (r, 0.0), (0.0, -r), (0.0, r)]
            .iter()
            .all(|(dx, dy)| (hf.height_at(p.x_mm + dx, p.y_mm + dy) - z0).abs() < 0.05 + 0.2 * r);
        if smooth {
            out.push(p.z_mm - z0);
        }
    }
    out
}

fn rms(e: &[f64]) -> f64 {
    (e.iter().map(|v| v * v).sum::<f64>() / e.len().max(1) as f64).sqrt()
}

#[test]
fn heights_on_flat_curved_and_tall_parts_match_the_truth() {
    let sensor = Sensor::default();
    let cal = calibration(&sensor);
    // A 10 mm plate with a gentle 40 mm wide, 3 mm high swell (slopes up to 13 degrees).
    let mut curved = Scene::flat_plate();
    curved.features.push(Feature::Bump {
        x_mm: 5.0,
        y_mm: 0.0,
        diameter_mm: 40.0,
        height_mm: 3.0,
    });
    let mut report = String::new();
    for (name, scene) in [
        ("flat plate", Scene::flat_plate()),
        ("curved plate", curved),
    ] {
        let (full, sim) = scan(&sensor, &cal, &scene, 3, ModelKind::Full);
        let e = errors(&full, &sim, 0.5, 1.0);
        let (lin, _) = scan(&sensor, &cal, &scene, 3, ModelKind::Linear);
        let el = errors(&lin, &sim, 0.5, 1.0);
        report += &format!(
            "{name}: full model RMS {:.4} mm over {} points; linear model RMS {:.4} mm\n",
            rms(&e),
            e.len(),
            rms(&el)
        );
        eprintln!("{name}: {} points, rms {:.4}", e.len(), rms(&e));
        assert!(e.len() > 3000, "{name}: {} points", e.len());
        // The target: 0.02 mm.
        assert!(rms(&e) <= 0.02, "{name}: {}", rms(&e));
    }
    // The 30 mm block: absolute error of its top.
    let (full, sim) = scan(&sensor, &cal, &Scene::block(), 3, ModelKind::Full);
    let e = errors(&full, &sim, 0.5, 25.0);
    let mean = e.iter().sum::<f64>() / e.len().max(1) as f64;
    report += &format!(
        "30 mm block top: mean error {mean:+.4} mm, RMS {:.4} mm over {} points\n",
        rms(&e),
        e.len()
    );
    eprint!("{report}");
    assert!(e.len() > 1000);
    assert!(mean.abs() <= 0.05, "block {mean}");
    // The range image of the flat plate: its top cells hold 10 mm.
    let (profiles, _) = scan(&sensor, &cal, &Scene::flat_plate(), 3, ModelKind::Full);
    let mut grid = RangeGrid::covering(
        &profiles,
        RangeParams {
            spacing_mm: [0.25, 0.25],
            ..RangeParams::default()
        },
    )
    .expect("grid");
    grid.accumulate(&profiles);
    let img = grid.image();
    let top: Vec<f32> = img.z.iter().copied().filter(|z| *z > 5.0).collect();
    let good = top.iter().filter(|z| (**z - 10.0).abs() < 0.05).count();
    assert!(top.len() > 3000, "{} top cells", top.len());
    assert!(
        good as f64 > 0.99 * top.len() as f64,
        "{good} of {}",
        top.len()
    );
}

#[test]
fn printed_texture_does_not_bend_heights_placed_by_their_peak_in_time() {
    let sensor = Sensor::default();
    let cal = calibration(&sensor);
    // A 5 mm plate printed in 1.2 mm cells of reflectance 0.25 to 0.95, scanned 0.1 mm a frame (the beam's
    // deviation along the travel is 0.30-0.42 mm).
    let mut scene = Scene::covering_plate(5.0);
    scene.features.push(Feature::Texture {
        x0_mm: -60.0,
        y0_mm: -50.0,
        x1_mm: 60.0,
        y1_mm: 50.0,
        cell_mm: 1.2,
        low: 0.25,
        high: 0.95,
        seed: 3,
    });
    let (mut profiles, images, travel, sim) =
        scan_every(&sensor, &cal, &scene, 21, 0.1, ModelKind::Full);
    let spatial = errors(&profiles, &sim, 0.5, 1.0);
    let st =
        Spacetime::for_scan(&sensor, &cal.full, 0.1).expect("the step is below the beam's width");
    let done = refine_in_time(&mut profiles, &images, &travel, &cal.full, &st);
    // Only points whose whole crossing lies inside the scan are placed: the middle frames.
    let middle: Vec<Profile> = profiles[st.half_window..21 - st.half_window].to_vec();
    let placed = middle
        .iter()
        .flat_map(|p| &p.points)
        .filter(|q| q.spacetime)
        .count();
    let all = middle.iter().map(|p| p.points.len()).sum::<usize>();
    let timed = errors(&middle, &sim, 0.5, 1.0);
    eprintln!(
        "textured plate: spatial RMS {:.4} mm, spacetime RMS {:.4} mm; {} of {} points placed in time ({placed} of {all} \
         in the middle frames)",
        rms(&spatial),
        rms(&timed),
        done.refined,
        done.points
    );
    assert!(placed as f64 > 0.9 * all as f64, "{placed} of {all}");
    assert!(
        rms(&timed) < 0.5 * rms(&spatial),
        "{} vs {}",
        rms(&timed),
        rms(&spatial)
    );
    // A coarse step is refused: one or two frames over the beam give no peak in time.
    assert!(Spacetime::for_scan(&sensor, &cal.full, 0.5).is_none());
}
