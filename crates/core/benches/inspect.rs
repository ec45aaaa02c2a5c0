//! Inspection of an 80 x 60 mm part's range image at a 0.1 mm grid (801 x 601 cells, plus 2 mm of belt around):
//! outlier removal, robust reference fit, characterization maps (deviation, normals, curvature), segmentation,
//! fuzzy classification and measurement of four defects (a bump, a dent, a hole and a scratch). Target (#6):
//! <= 50 ms on one core.

use stripe3d_core::accumulate::RangeImage;
use stripe3d_core::characterize::{
    CharacterizeParams, PreparedGolden, ReferenceShape, ReferenceSource,
};
use stripe3d_core::detect::{DetectParams, SurfaceRules, bell, inspect};

fn main() {
    divan::main();
}

/// The part, with its four defects or (`defects` false) without them: a golden scan of a good part.
fn part_with(defects: bool) -> RangeImage {
    let (w, h) = (841, 641);
    let mut r = RangeImage {
        origin_mm: [-42.0, 32.0],
        spacing_mm: [0.1, 0.1],
        width: w,
        height: h,
        z: vec![0.0; w * h],
        intensity: None,
    };
    for j in 0..h {
        for i in 0..w {
            let (x, y) = (-42.0 + i as f64 * 0.1, 32.0 - j as f64 * 0.1);
            // Deterministic noise of about 0.007 mm.
            let n = (((i * 7919 + j * 104_729) % 1000) as f64 / 1000.0 - 0.5) * 0.024;
            let z = if x.abs() > 40.0 || y.abs() > 30.0 {
                n.abs()
            } else if !defects {
                10.0 + n
            } else if (x - 10.0).hypot(y + 10.0) < 2.0 {
                f64::NAN
            } else {
                10.0 + 0.3 * bell((x + 20.0).hypot(y - 10.0), 3.0)
                    - 0.2 * bell((x - 15.0).hypot(y - 12.0), 2.5)
                    - if (y + 20.0).abs() < 0.3 && x.abs() < 10.0 {
                        0.2
                    } else {
                        0.0
                    }
                    + n
            };
            r.z[j * w + i] = z as f32;
        }
    }
    r
}

fn part() -> RangeImage {
    part_with(true)
}

#[divan::bench]
fn inspect_80x60mm_at_0_1mm(b: divan::Bencher) {
    let r = part();
    let mut rules = SurfaceRules::shipped().expect("rules");
    let cp = CharacterizeParams::default();
    let dp = DetectParams::default();
    b.bench_local(|| {
        let i = inspect(
            &r,
            ReferenceSource::Fit(ReferenceShape::Plane),
            &cp,
            &mut rules,
            &dp,
        )
        .expect("inspect");
        assert_eq!(i.detection.defects.len(), 4, "{:?}", i.detection.defects);
        divan::black_box(i)
    });
}

/// Times inspecting the part against a golden scan of a good one, prepared once (`prepare`) or as it is, scanned at
/// 0.5 mm per frame (the golden scan's walls reach a travel step along x).
fn bench_golden(b: divan::Bencher, prepare: bool) {
    let r = part();
    let golden = part_with(false);
    let mut rules = SurfaceRules::shipped().expect("rules");
    let cp = CharacterizeParams::default();
    let dp = DetectParams {
        travel_step_mm: Some(0.5),
        ..DetectParams::default()
    };
    let prepared = prepare
        .then(|| PreparedGolden::new(&golden, dp.outlier_mm, cp.belt_level_mm, dp.travel_step_mm));
    b.bench_local(|| {
        let source = match &prepared {
            Some(p) => ReferenceSource::Prepared(p),
            None => ReferenceSource::Golden(&golden),
        };
        let i = inspect(&r, source, &cp, &mut rules, &dp).expect("inspect");
        divan::black_box(i)
    });
}

/// The same part against a golden scan of a good one (registration, then the golden heights within the
/// registration's tolerance as the reference) instead of a fitted plane.
#[divan::bench]
fn inspect_80x60mm_at_0_1mm_against_golden(b: divan::Bencher) {
    bench_golden(b, false);
}

/// The same against the golden scan prepared once (cleaned, its wall spans mapped: `PreparedGolden`), as a line
/// inspecting many parts of one product does: the per-part cost.
#[divan::bench]
fn inspect_80x60mm_at_0_1mm_against_prepared_golden(b: divan::Bencher) {
    bench_golden(b, true);
}

/// Registration alone (the golden inspection's first step).
#[divan::bench]
fn register_80x60mm_at_0_1mm(b: divan::Bencher) {
    let r = part();
    let golden = part_with(false);
    b.bench_local(|| {
        divan::black_box(
            stripe3d_core::characterize::register(
                &r,
                &golden,
                &stripe3d_core::characterize::RegisterParams::default(),
            )
            .expect("register"),
        )
    });
}
