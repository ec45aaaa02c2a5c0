//! Stripe extraction measured against the simulator's exact ground truth (tolerances stated per test).

use stripe3d_core::extract::{ExtractParams, Extraction, Extractor, Method};
use stripe3d_core::{Image, Sensor};
use stripe3d_sim::evaluate::Score;
use stripe3d_sim::{EdgeMap, Frame, RenderOptions, Scene, Simulator};

fn score(frames: &[Frame], bits: u8, method: Method) -> Score {
    score_where(frames, bits, method, None).0
}

/// [`score`], and with `edges` (one map per frame) the score of the points away from the edges as well.
fn score_where(
    frames: &[Frame],
    bits: u8,
    method: Method,
    edges: Option<&[EdgeMap]>,
) -> (Score, Score) {
    let mut clean = Score::default();
    let mut ex = Extractor::new(ExtractParams {
        method,
        ..ExtractParams::default()
    })
    .expect("extractor");
    let mut out = Extraction::default();
    let mut s = Score::default();
    let mut clean_frame = 0;
    for f in frames {
        if bits <= 8 {
            let data: Vec<u8> = f.image.data().iter().map(|&v| v as u8).collect();
            let img = Image::from_vec(f.image.width(), f.image.height(), data).expect("image");
            ex.extract_into(img.view(), &mut out);
        } else {
            ex.extract_into(f.image.view(), &mut out);
        }
        let pts: Vec<(u32, f64)> = out.points.iter().map(|p| (p.row, p.x)).collect();
        s.add(&f.truth, &pts);
        if let Some(e) = edges.and_then(|e| e.get(clean_frame)) {
            clean.add_where(&f.truth, &pts, |row, x| !e.near(row, x));
        }
        clean_frame += 1;
    }
    (s, clean)
}

#[test]
fn noise_free_plate_every_truth_point_is_found_to_a_fiftieth_of_a_pixel() {
    let mut sensor = Sensor::default();
    sensor.camera.bits = 16;
    sensor.camera.k1 = -0.05;
    let sim =
        Simulator::new(&sensor, &Scene::covering_plate(8.0), RenderOptions::ideal()).expect("sim");
    let frames = vec![sim.render(0, 0.0)];
    for m in [Method::Gaussian, Method::Steger, Method::BlaisRioux8] {
        let s = score(&frames, 16, m);
        assert_eq!(
            s.found,
            s.truth,
            "{}: all {} truth points",
            m.name(),
            s.truth
        );
        assert_eq!(s.false_points, 0, "{}", m.name());
        // Tolerance: the stripe's irradiance varies across its width (1/r, cosine), which moves its intensity
        // centre off the sheet's centre plane by a few thousandths of a pixel.
        assert!(s.rms() < 0.02, "{}: rms {}", m.name(), s.rms());
    }
}

#[test]
fn noisy_plate_detection_and_accuracy() {
    let mut sensor = Sensor::default();
    sensor.camera.k1 = -0.05;
    let opts = RenderOptions {
        gloss: false,
        ..RenderOptions::default()
    };
    let frames: Vec<Frame> = [6.0, 9.3, 12.7]
        .iter()
        .enumerate()
        .map(|(k, &z)| {
            Simulator::new(&sensor, &Scene::covering_plate(z), opts.clone())
                .expect("sim")
                .render(k, 0.0)
        })
        .collect();
    for m in [Method::Steger, Method::BlaisRioux8] {
        let s = score(&frames, 8, m);
        // Default noise, speckle and blur on a matte plate: everything found, nothing invented, RMS well under
        // 0.1 px (speckle dominates).
        assert!(
            s.detection_rate() > 0.999,
            "{}: detection {}",
            m.name(),
            s.detection_rate()
        );
        assert!(
            s.false_rate() < 0.001,
            "{}: false {}",
            m.name(),
            s.false_rate()
        );
        assert!(s.rms() < 0.08, "{}: rms {}", m.name(), s.rms());
    }
}

#[test]
fn demo_scene_with_ghosts_does_not_regress() {
    // The target (>= 99.5 % within 0.5 px, <= 0.1 % false points) is not met over the whole scene: edges of
    // the part light half a stripe (beam tails on corners, occluding edges, albedo edges), which every estimator
    // places off the sheet. This guards the level measured when the extractor landed, and the target away from
    // the edges.
    let sensor = Sensor::default();
    let sim = Simulator::new(&sensor, &Scene::demo(), RenderOptions::default()).expect("sim");
    let frames: Vec<Frame> = (0..4).map(|k| sim.render(k * 5, k as f64 * 2.5)).collect();
    let edges: Vec<EdgeMap> = (0..4).map(|k| sim.edge_map(k as f64 * 2.5)).collect();
    let (s, clean) = score_where(&frames, 8, Method::Steger, Some(&edges));
    eprintln!(
        "all: {:.4} / {:.5}; away from edges: {:.4} / {:.5} ({} of {} truth points)",
        s.detection_rate(),
        s.false_rate(),
        clean.detection_rate(),
        clean.false_rate(),
        clean.truth,
        s.truth
    );
    assert!(
        s.detection_rate() > 0.97,
        "detection {}",
        s.detection_rate()
    );
    assert!(s.false_rate() < 0.06, "false points {}", s.false_rate());
    // Away from the edges of the visible surface (walls, rims, laser shadows, albedo edges) the misses and most
    // false points are gone (the glossy patch's ghosts do not add to what is left: measured with gloss off).
    assert!(
        clean.truth > 9 * s.truth / 10,
        "{} of {} truth points away from edges",
        clean.truth,
        s.truth
    );
    assert!(
        clean.detection_rate() > 0.995,
        "detection away from edges {}",
        clean.detection_rate()
    );
    // 0.050% on these frames; 0.115% while the edge map compared each pixel with its left neighbour only (a rim
    // running along the rows went unmarked).
    assert!(
        clean.false_rate() <= 0.001,
        "false points away from edges {}",
        clean.false_rate()
    );
}
