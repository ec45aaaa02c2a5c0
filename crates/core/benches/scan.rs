//! Per-frame cost of the stages after extraction: stripe coding, triangulation, accumulation, on a 648x480 frame
//! of the paper's set-up with 11 stripes on a 10 mm plate (5,280 points).
//! A whole depth image (22 frames) with and without the curvature-bias correction, on a wavy surface.
//! The spacetime analysis of one frame's points over 5 frames on each side.
//! One core unless `RAYON_NUM_THREADS` is set.

use stripe3d_core::Sensor;
use stripe3d_core::accumulate::{ModelKind, Profile, RangeGrid, RangeParams, profile_into};
use stripe3d_core::code::{Coding, CodingParams, StripeCoder};
use stripe3d_core::curvature::CurvatureBias;
use stripe3d_core::extract::Method;
use stripe3d_core::extract::StripePoint;
use stripe3d_core::triangulate::FullModel;

fn main() {
    // One core, as the figures are quoted: the chain's parallel parts (reconciliation, triangulation, accumulation)
    // on a pool of one thread, unless RAYON_NUM_THREADS asks for more.
    if std::env::var_os("RAYON_NUM_THREADS").is_none() {
        // Fails only when a global pool exists already, which nothing here makes.
        let _ = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build_global();
    }
    divan::main();
}

fn frame() -> (FullModel, Vec<StripePoint>) {
    let sensor = Sensor::default();
    let model = FullModel::nominal(&sensor);
    let mut pts = Vec::new();
    for row in 0..480u32 {
        for k in 0..11 {
            if let Some(u) = model.column_at_height(k, f64::from(row), 10.0)
                && (0.0..647.0).contains(&u)
            {
                pts.push(StripePoint {
                    row,
                    x: u,
                    intensity: 150.0,
                    width: 5.0,
                    score: 1.0,
                    cut: false,
                });
            }
        }
    }
    (model, pts)
}

#[divan::bench]
fn code_frame(b: divan::Bencher) {
    let (model, pts) = frame();
    let mut coder = StripeCoder::new(&model, 648, 480, CodingParams::default()).expect("coder");
    let mut out = Coding::default();
    b.bench_local(|| {
        coder.code_into(divan::black_box(&pts), &mut out);
        out.stats.coded
    });
}

#[divan::bench]
fn triangulate_frame(b: divan::Bencher) {
    let (model, pts) = frame();
    let mut coder = StripeCoder::new(&model, 648, 480, CodingParams::default()).expect("coder");
    let mut coding = Coding::default();
    coder.code_into(&pts, &mut coding);
    let mut p = Profile::default();
    b.bench_local(|| {
        profile_into(
            0,
            0.0,
            divan::black_box(&pts),
            &coding,
            &model,
            None,
            ModelKind::Full,
            &mut p,
        );
        p.points.len()
    });
}

/// 20 frames 0.5 mm apart (the same points moving along the belt), triangulated, and the range-grid parameters.
fn twenty_profiles() -> (Vec<Profile>, RangeParams) {
    let (model, pts) = frame();
    let mut coder = StripeCoder::new(&model, 648, 480, CodingParams::default()).expect("coder");
    let mut coding = Coding::default();
    coder.code_into(&pts, &mut coding);
    let profiles: Vec<Profile> = (0..20)
        .map(|k| {
            let mut p = Profile::default();
            profile_into(
                k,
                0.5 * k as f64,
                &pts,
                &coding,
                &model,
                None,
                ModelKind::Full,
                &mut p,
            );
            p
        })
        .collect();
    let params = RangeParams {
        spacing_mm: [0.22, 0.22],
        ..RangeParams::default()
    };
    (profiles, params)
}

/// Accumulation of the 20 frames onto a grid made beforehand: the work that grows with the frames (tracks, samples
/// and the cells filled between them). The cost per frame is the total over 20.
#[divan::bench]
fn accumulate_frame(b: divan::Bencher) {
    let (profiles, params) = twenty_profiles();
    let mut g = RangeGrid::covering(&profiles, params).expect("grid");
    b.bench_local(|| {
        g.accumulate(divan::black_box(&profiles));
    });
}

/// The part of accumulation paid once per scan: the grid covering it (allocated and zeroed) and the range image
/// made of it, here for the 20 frames' 104 x 94 mm (471 x 427 cells of 0.22 mm). A longer scan pays it once over more
/// frames.
#[divan::bench]
fn range_grid_per_scan(b: divan::Bencher) {
    let (profiles, params) = twenty_profiles();
    b.bench_local(|| {
        let g = RangeGrid::covering(divan::black_box(&profiles), params.clone()).expect("grid");
        g.image().width
    });
}

/// 22 frames 0.5 mm apart (one depth image) of a wavy surface (1 mm amplitude, curvature up to 0.25/mm: every point
/// is corrected): the range image with and without the curvature-bias correction (`stripe3d scan`'s default).
fn wavy_depth_image() -> (Sensor, FullModel, Vec<Profile>) {
    let sensor = Sensor::default();
    let (model, pts) = frame();
    let mut coder = StripeCoder::new(&model, 648, 480, CodingParams::default()).expect("coder");
    let mut coding = Coding::default();
    coder.code_into(&pts, &mut coding);
    let profiles = (0..22)
        .map(|k| {
            let mut p = Profile::default();
            profile_into(
                k,
                0.5 * k as f64,
                &pts,
                &coding,
                &model,
                None,
                ModelKind::Full,
                &mut p,
            );
            for q in &mut p.points {
                q.z_mm += (q.x_mm / 2.0).sin() * (q.y_mm / 2.0).sin();
            }
            p
        })
        .collect();
    (sensor, model, profiles)
}

#[divan::bench]
fn depth_image_uncorrected(b: divan::Bencher) {
    let (sensor, _, profiles) = wavy_depth_image();
    let grid = [sensor.camera.belt_pixel_mm(); 2];
    b.bench_local(|| {
        stripe3d_core::scan::range_image(divan::black_box(&profiles), grid)
            .expect("range")
            .width
    });
}

#[divan::bench]
fn depth_image_curvature_corrected(b: divan::Bencher) {
    let (sensor, model, profiles) = wavy_depth_image();
    let grid = [sensor.camera.belt_pixel_mm(); 2];
    let bias = CurvatureBias::new(&sensor, &model, Method::Steger).expect("a Steger sensor");
    b.bench_local(|| {
        let mut p = profiles.clone();
        let (r, n) =
            stripe3d_core::scan::range_image_corrected(&mut p, grid, Some(&bias)).expect("range");
        assert!(n > 50_000, "{n} points corrected");
        r.width
    });
}

/// Spacetime analysis of one frame's 5,280 points over 5 frames on each side (0.2 mm a frame): frames of Gaussian
/// stripes (1.6 px) at the plate's columns, which a flat plate keeps still while it moves.
#[divan::bench]
fn spacetime_frame(b: divan::Bencher) {
    use stripe3d_core::image::Image;
    use stripe3d_core::spacetime::Spacetime;
    let (model, pts) = frame();
    let mut coder = StripeCoder::new(&model, 648, 480, CodingParams::default()).expect("coder");
    let mut coding = Coding::default();
    coder.code_into(&pts, &mut coding);
    let mut image = Image::<u8>::new(648, 480);
    for p in &pts {
        let row = p.row as usize * 648;
        let lo = (p.x - 6.0).max(0.0) as usize;
        let hi = ((p.x + 6.0) as usize).min(647);
        for u in lo..=hi {
            let d = u as f64 - p.x;
            let v = 200.0 * (-d * d / (2.0 * 1.6 * 1.6)).exp();
            let px = &mut image.data_mut()[row + u];
            *px = (*px as f64 + v).min(255.0) as u8;
        }
    }
    let frames: Vec<Image<u8>> = (0..11).map(|_| image.clone()).collect();
    let travel: Vec<f64> = (0..11).map(|k| 0.2 * k as f64).collect();
    let st = Spacetime {
        half_window: 5,
        sigma_travel_mm: 0.32,
    };
    let mut base = Profile::default();
    profile_into(
        5,
        travel[5],
        &pts,
        &coding,
        &model,
        None,
        ModelKind::Full,
        &mut base,
    );
    let mut check = base.clone();
    let done = st.refine(&mut check, &frames, &travel, &model);
    assert!(
        done.refined * 10 > done.points * 9,
        "{done:?}: the still stripes are whole peaks in time"
    );
    b.bench_local(|| {
        let mut p = base.clone();
        st.refine(&mut p, divan::black_box(&frames), &travel, &model)
            .refined
    });
}
