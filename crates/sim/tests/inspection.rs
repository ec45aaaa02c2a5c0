//! Inspection through the whole chain (render, extract, code, triangulate, accumulate, characterize, detect),
//! against the simulator's defect truth: one plate with random defects, one clean plate. The population figures
//! (recall, precision, measurement tolerances over hundreds of defects) come from `stripe3d bench defects`.

use stripe3d_core::Sensor;
use stripe3d_core::characterize::{CharacterizeParams, ReferenceShape, ReferenceSource};
use stripe3d_core::detect::{DetectParams, SurfaceRules, inspect};
use stripe3d_sim::pipeline::{calibrate_sensor, frames_for_sweep, scan_scene};
use stripe3d_sim::{RenderOptions, Scene};

#[test]
fn defects_are_found_named_and_measured_and_clean_plates_stay_clean() {
    let sensor = Sensor::default();
    let cal = calibrate_sensor(&sensor, 500).expect("calibration");
    let frames = frames_for_sweep(&sensor, 2);
    let mut rules = SurfaceRules::shipped().expect("rules");
    let run = |scene: &Scene, seed: u64, rules: &mut SurfaceRules| {
        let opts = RenderOptions {
            seed,
            ..RenderOptions::default()
        };
        let scan = scan_scene(&sensor, &cal, scene, frames, opts, [0.22, 0.22]).expect("scan");
        // The travel between frames of the conveyor `scan_scene` moves the part with (hole areas use it).
        let params = DetectParams {
            travel_step_mm: Some(sensor.conveyor.clone().unwrap_or_default().step_mm()),
            ..DetectParams::default()
        };
        let i = inspect(
            &scan.range,
            ReferenceSource::Fit(ReferenceShape::Plane),
            &CharacterizeParams::default(),
            rules,
            &params,
        )
        .expect("inspect");
        (i.detection, scan.simulator.defects().to_vec())
    };
    // Defects of 0.1 mm and more, 2 mm and wider (the targets), tolerances as the issue states them.
    let (found, truth) = run(&Scene::defect_plate(2, 4), 2, &mut rules);
    assert_eq!(truth.len(), 4);
    for t in &truth {
        let f = found
            .defects
            .iter()
            .find(|f| (f.centroid_mm[0] - t.x_mm).hypot(f.centroid_mm[1] - t.y_mm) < 0.5)
            .unwrap_or_else(|| panic!("{t:?} not found within 0.5 mm in {:#?}", found.defects));
        assert_eq!(f.kind.name(), t.kind, "{t:?} -> {f:?}");
        assert!(
            (f.area_mm2 - t.area_mm2).abs() <= 0.15 * t.area_mm2,
            "area: {t:?} -> {f:?}"
        );
        assert!(
            (f.depth_mm - t.depth_mm).abs() <= 0.03,
            "depth: {t:?} -> {f:?}"
        );
    }
    assert_eq!(
        found.defects.len(),
        truth.len(),
        "no false defects: {:#?}",
        found.defects
    );
    let (clean, _) = run(&Scene::flat_plate(), 3, &mut rules);
    assert!(clean.defects.is_empty(), "{:#?}", clean.defects);
}
