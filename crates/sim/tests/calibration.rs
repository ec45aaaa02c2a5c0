//! Calibration from simulated plate images, checked against the simulator's true laser sheets.

use stripe3d_core::CoreError;
use stripe3d_core::calibrate::{CalibrationError, CalibrationParams, PlaneImage, calibrate};
use stripe3d_core::extract::{ExtractParams, Extractor, Method};
use stripe3d_core::{Image, Sensor};
use stripe3d_sim::{RenderOptions, Scene, Simulator};

fn plate_image(sensor: &Sensor, z: f64, seed: u64) -> PlaneImage {
    let scene = if z == 0.0 {
        Scene::empty_belt()
    } else {
        Scene::covering_plate(z)
    };
    let opts = RenderOptions {
        seed,
        ..RenderOptions::default()
    };
    let frame = Simulator::new(sensor, &scene, opts)
        .expect("sim")
        .render(0, 0.0);
    let data: Vec<u8> = frame
        .image
        .data()
        .iter()
        .map(|&v| v.min(255) as u8)
        .collect();
    let img = Image::from_vec(frame.image.width(), frame.image.height(), data).expect("image");
    let mut ex = Extractor::new(ExtractParams {
        method: Method::Steger,
        ..ExtractParams::default()
    })
    .expect("extractor");
    let mut out = Default::default();
    ex.extract_into(img.view(), &mut out);
    PlaneImage {
        name: format!("plate-{z}mm.png"),
        height_mm: z,
        points: out.points,
    }
}

fn images(sensor: &Sensor, heights: &[f64]) -> Vec<PlaneImage> {
    heights
        .iter()
        .enumerate()
        .map(|(i, &z)| plate_image(sensor, z, 10 + i as u64))
        .collect()
}

#[test]
fn planes_fitted_from_five_heights_match_the_true_sheets() {
    let mut sensor = Sensor::default();
    sensor.camera.k1 = -0.05;
    let imgs = images(&sensor, &[0.0, 5.0, 10.0, 20.0, 30.0]);
    let cal = calibrate(&sensor, &imgs, &CalibrationParams::default()).expect("calibrates");
    assert_eq!(cal.full.planes.len(), 11);
    // Compare with the true sheets: the height each model gives for true sheet points over the fitted range.
    let mut worst = 0.0f64;
    for k in 0..11 {
        for z in [2.0, 12.0, 28.0] {
            for y in [-30.0, 0.0, 30.0] {
                let p = nalgebra::Vector3::new(sensor.laser.sheet_x_mm(k, z), y, z);
                let Some((u, v)) = sensor.camera.project(&p) else {
                    continue;
                };
                if !(0.0..648.0).contains(&u) {
                    continue;
                }
                let h = cal.full.height(k, u, v).expect("height");
                worst = worst.max((h - z).abs());
            }
        }
        let r = &cal.stripes[k];
        eprintln!(
            "stripe {k}: heights {:?} full rms {:.4} max {:.4} linear rms {:.4} max {:.4}",
            r.heights_mm, r.full_rms_mm, r.full_max_mm, r.linear_rms_mm, r.linear_max_mm
        );
        assert!(r.full_rms_mm < 0.02, "stripe {k}: {}", r.full_rms_mm);
    }
    eprintln!("worst height error against the true sheets: {worst:.4} mm");
    // Tolerance: 0.01 mm, half the scanning issue's height target.
    assert!(worst < 0.01, "worst {worst}");
}

#[test]
fn too_few_heights_duplicates_and_mislabelled_images_are_refused() {
    let sensor = Sensor::default();
    let p = CalibrationParams::default();
    let imgs = images(&sensor, &[0.0, 4.0, 8.0, 12.0]);
    let err = calibrate(&sensor, &imgs[..2], &p).expect_err("two heights");
    assert_eq!(
        err,
        CoreError::Calibration(CalibrationError::TooFewPlates { given: 2 })
    );
    assert!(err.to_string().contains("three heights"), "{err}");
    let mut dup = imgs[..3].to_vec();
    dup[2].height_mm = 4.0;
    let err = calibrate(&sensor, &dup, &p).expect_err("duplicate");
    assert!(
        matches!(&err, CoreError::Calibration(CalibrationError::SameHeight { height_mm, .. }) if *height_mm == 4.0),
        "{err:?}"
    );
    assert!(err.to_string().contains("both labelled"), "{err}");
    // Two images swapped.
    let mut swapped = imgs.clone();
    swapped[1].height_mm = 8.0;
    swapped[2].height_mm = 4.0;
    let err = calibrate(&sensor, &swapped, &p).expect_err("swapped");
    eprintln!("swapped: {err}");
    // One height off by 0.5 mm: the image is named.
    let mut wrong = imgs.clone();
    wrong[2].height_mm = 8.5;
    let err = calibrate(&sensor, &wrong, &p).expect_err("mislabelled");
    eprintln!("mislabelled: {err}");
    assert!(err.to_string().contains("plate-8mm.png"), "{err}");
    assert!(
        matches!(&err, CoreError::Calibration(CalibrationError::ImageOffPlanes { image, height_mm, .. })
            if image == "plate-8mm.png" && *height_mm == 8.5),
        "{err:?}"
    );
}

#[test]
fn a_stripe_broken_into_two_pieces_is_one_stripe() {
    // The first stripe of the 20 mm plate loses its middle rows (dimmed, or bent out of the image by the lens):
    // two long pieces at one column, which are one stripe, not two.
    let sensor = Sensor::default();
    let mut imgs = images(&sensor, &[0.0, 5.0, 10.0, 20.0, 30.0]);
    let whole = calibrate(&sensor, &imgs, &CalibrationParams::default()).expect("calibrates");
    let plate = &mut imgs[3];
    let first = plate
        .points
        .iter()
        .filter(|p| p.row == 240)
        .map(|p| p.x)
        .fold(f64::INFINITY, f64::min);
    let before = plate.points.len();
    plate
        .points
        .retain(|p| !((p.x - first).abs() < 5.0 && (150..330).contains(&p.row)));
    assert!(
        plate.points.len() + 150 < before,
        "the cut removed the rows"
    );
    let cal = calibrate(&sensor, &imgs, &CalibrationParams::default()).expect("calibrates");
    assert_eq!(cal.full.planes.len(), 11);
    for (k, r) in cal.stripes.iter().enumerate() {
        assert_eq!(r.heights_mm, whole.stripes[k].heights_mm, "stripe {k}");
        assert!(r.full_rms_mm < 0.02, "stripe {k}: {}", r.full_rms_mm);
    }
}
