//! Detection on synthetic range images: each kind found, measured and classified; clean surfaces, edges and
//! gaps left alone.

use super::*;
use std::collections::VecDeque;

#[test]
fn hole_areas_are_corrected_for_the_travel_step() {
    use crate::accumulate::{Profile, ProfilePoint, RangeGrid, RangeParams};
    // A 10 mm plate with a 2.5 mm x 4.4 mm slot, sampled as one stripe sweeps it: every 0.5 mm along x (at
    // one phase for the whole scan), on every grid row; no sample falls in the slot. (A slot, not a round
    // hole: where a round hole's chord is shorter than the accumulation's fill distance, its caps are filled
    // over and lost, which no correction of the measured rows can see.)
    let (step, w, h) = (0.5, 2.5, 4.4);
    let truth = w * h;
    let (mut raw_err, mut corrected_err) = (0.0f64, 0.0f64);
    let phases = [0.0, 0.1, 0.2, 0.3, 0.4];
    for phase in phases {
        let profiles: Vec<Profile> = (0..40)
            .map(|k| {
                let x = -10.0 + phase + k as f64 * step;
                Profile {
                    frame: k,
                    travel_mm: k as f64 * step,
                    points: (0..100)
                        .map(|row| (row, -11.11 + 0.22 * row as f64))
                        .filter(|&(_, y)| x.abs() > 0.5 * w || y.abs() > 0.5 * h)
                        .map(|(row, y)| ProfilePoint {
                            stripe: 0,
                            row,
                            u: 0.0,
                            x_mm: x,
                            y_mm: y,
                            z_mm: 10.0,
                            intensity: 100.0,
                            spacetime: false,
                        })
                        .collect(),
                }
            })
            .collect();
        let params = RangeParams {
            spacing_mm: [0.22, 0.22],
            ..RangeParams::default()
        };
        let mut grid = RangeGrid::covering(&profiles, params).expect("grid");
        grid.accumulate(&profiles);
        let range = grid.image();
        // The slot: the unmeasured cells within 4 mm of its centre.
        let slot: Vec<usize> = (0..range.width * range.height)
            .filter(|&k| {
                let x = range.origin_mm[0] + (k % range.width) as f64 * 0.22;
                let y = range.origin_mm[1] - (k / range.width) as f64 * 0.22;
                x.hypot(y) < 4.0 && range.z[k].is_nan()
            })
            .collect();
        let n = phases.len() as f64;
        raw_err += (hole_area(&range, &slot, None) - truth) / truth / n;
        corrected_err += (hole_area(&range, &slot, Some(step)) - truth) / truth / n;
    }
    // Uncorrected, the slot is one step less a cell longer along x than it is (0.28 mm on 2.5: +11%).
    assert!(raw_err > 0.08, "raw {raw_err}, corrected {corrected_err}");
    assert!(
        corrected_err.abs() < 0.03,
        "corrected {corrected_err}, raw {raw_err}"
    );
}

#[test]
fn a_partly_lit_sheet_at_a_rim_is_not_taken_for_a_travel_steps_sampling() {
    // One grid row of 0.1 mm cells: plate, a gap of 20 cells, plate; 100 grey levels everywhere but the cell
    // left of the gap (a partly lit sheet's sample, 30) when `dim`. Travel step 0.5 mm: a full sheet's end
    // loses (0.5 - 0.1) / 2 = 0.2 mm = 2 cells.
    let row = |dim: bool, intensities: bool| {
        let w = 60;
        let mut z = vec![10.0f32; w];
        let mut i = vec![100.0f32; w];
        for k in 20..40 {
            z[k] = f32::NAN;
            i[k] = f32::NAN;
        }
        if dim {
            i[19] = 30.0;
        }
        RangeImage {
            origin_mm: [0.0, 0.0],
            spacing_mm: [0.1, 0.1],
            width: w,
            height: 1,
            z,
            intensity: intensities.then_some(i),
        }
    };
    let gap: Vec<usize> = (20..40).collect();
    let cells = |r: &RangeImage| hole_area(r, &gap, Some(0.5)) / 0.01;
    // Two full ends: 20 - 2 - 2 cells.
    assert!((cells(&row(false, true)) - 16.0).abs() < 1e-9);
    // A partly lit sheet at the left rim: no excess there, and half its cell back (it reaches into the hole).
    assert!(
        (cells(&row(true, true)) - 18.5).abs() < 1e-9,
        "{}",
        cells(&row(true, true))
    );
    // Without intensities nothing tells: both ends are full sheets'.
    assert!((cells(&row(true, false)) - 16.0).abs() < 1e-9);
    // A dim cell whose row holds too little beyond it to compare with is taken as a full sheet's.
    let mut short = row(true, true);
    for k in 0..15 {
        short.z[k] = f32::NAN;
    }
    assert!((cells(&short) - 16.0).abs() < 1e-9, "{}", cells(&short));
}

const NEIGHBOURS8: [(i64, i64); 8] = [
    (-1, 0),
    (1, 0),
    (0, -1),
    (0, 1),
    (-1, -1),
    (1, -1),
    (-1, 1),
    (1, 1),
];

/// Breadth-first labelling: the slow, obviously correct reference of [`components`].
fn components_bfs(w: usize, h: usize, mask: &[bool], eight: bool) -> (Vec<u32>, Vec<usize>) {
    let mut label = vec![0u32; w * h];
    let mut sizes = vec![0usize];
    let mut queue = VecDeque::new();
    for start in 0..w * h {
        if label[start] != 0 || !mask[start] {
            continue;
        }
        let id = sizes.len() as u32;
        let mut n = 0usize;
        label[start] = id;
        queue.push_back(start);
        while let Some(k) = queue.pop_front() {
            n += 1;
            let (i, j) = ((k % w) as i64, (k / w) as i64);
            for (di, dj) in NEIGHBOURS8 {
                if !eight && di != 0 && dj != 0 {
                    continue;
                }
                let (a, b) = (i + di, j + dj);
                if a < 0 || b < 0 || a >= w as i64 || b >= h as i64 {
                    continue;
                }
                let kk = b as usize * w + a as usize;
                if label[kk] == 0 && mask[kk] {
                    label[kk] = id;
                    queue.push_back(kk);
                }
            }
        }
        sizes.push(n);
    }
    (label, sizes)
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(500))]
    /// The run-based labelling equals breadth-first search, label for label, in 4 and 8 connectivity.
    #[test]
    fn run_labelling_equals_breadth_first_search(
        w in 1usize..24,
        h in 1usize..24,
        density in 0.0f64..1.0,
        seed in 0u64..1_000_000,
    ) {
        let mut x = seed.wrapping_mul(6364136223846793005).wrapping_add(1);
        let mask: Vec<bool> = (0..w * h)
            .map(|_| {
                x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                ((x >> 33) as f64 / (1u64 << 31) as f64) < density
            })
            .collect();
        for eight in [false, true] {
            let fast = components(w, h, |k| mask[k], eight);
            let slow = components_bfs(w, h, &mask, eight);
            proptest::prop_assert_eq!(&fast, &slow, "eight = {}", eight);
        }
    }
}
use crate::characterize::{CharacterizeParams, fit_reference, surface_maps};

/// A 40 x 30 mm, 10 mm plate on the belt on a 0.2 mm grid, with `f` added to its top.
fn plate(f: impl Fn(f64, f64) -> Option<f64>) -> RangeImage {
    let (w, h) = (250, 200);
    let mut r = RangeImage {
        origin_mm: [-25.0, 20.0],
        spacing_mm: [0.2, 0.2],
        width: w,
        height: h,
        z: vec![0.0; w * h],
        intensity: None,
    };
    for j in 0..h {
        for i in 0..w {
            let (x, y) = cell_xy(&r, i, j);
            let on = x.abs() <= 20.0 && y.abs() <= 15.0;
            // Deterministic pseudo-noise of about 0.007 mm.
            let n = (((i * 7919 + j * 104_729) % 1000) as f64 / 1000.0 - 0.5) * 0.024;
            r.z[j * w + i] = if on {
                match f(x, y) {
                    Some(dz) => (10.0 + dz + n) as f32,
                    None => f32::NAN,
                }
            } else {
                n.abs() as f32
            };
        }
    }
    r
}

/// The characterization maps of `r` against its fitted plane.
fn plane_maps(r: &RangeImage) -> SurfaceMaps {
    let p = CharacterizeParams::default();
    let reference = fit_reference(r, &p).expect("fit");
    surface_maps(r, reference.heights(r), &p).expect("maps")
}

fn run(r: &RangeImage) -> Detection {
    let mut rules = SurfaceRules::shipped().expect("rules");
    detect(r, &plane_maps(r), &mut rules, &DetectParams::default()).expect("detect")
}

#[test]
fn a_holes_wall_is_part_of_the_hole_not_an_anomaly() {
    // A 6 mm through-hole whose far wall is seen in perspective: a crescent inside the hole's right rim where the
    // heights fall steeply from the surface towards the belt.
    let r = plate(|x, y| {
        let d = x.hypot(y);
        if d >= 3.0 {
            Some(0.0)
        } else if x > 1.2 && d > 2.2 {
            Some(-12.0 * (3.0 - d))
        } else {
            None
        }
    });
    let d = run(&r);
    assert_eq!(d.defects.len(), 1, "{:?}", d.defects);
    assert_eq!(d.defects[0].kind, DefectKind::Hole);
    assert!(
        d.candidates
            .iter()
            .any(|c| c.kind == DefectKind::Anomaly && !c.reported && c.defect.is_none()),
        "the wall was weighed as an anomaly and merged: {:?}",
        d.candidates
    );
}

#[test]
fn a_golden_scans_wrong_index_fragments_are_not_held_against_the_part() {
    // The golden scan has a thin column of heights 3 mm low (one stripe coded one index off over 20 rows);
    // the part is clean. Uncleaned, the column would stand in the reference as a pit the part "fills".
    let part = plate(|_, _| Some(0.0));
    let mut golden = plate(|_, _| Some(0.0));
    for j in 80..100 {
        golden.z[j * golden.width + 120] -= 3.0;
    }
    let mut rules = SurfaceRules::shipped().expect("rules");
    let i = inspect(
        &part,
        ReferenceSource::Golden(&golden),
        &CharacterizeParams::default(),
        &mut rules,
        &DetectParams::default(),
    )
    .expect("inspect");
    assert!(i.detection.defects.is_empty(), "{:?}", i.detection.defects);
}

#[test]
fn a_prepared_golden_scan_inspects_as_the_golden_scan_and_refuses_other_parameters() {
    // A part with a dent, against a golden scan with a wrong-index column (cleaned by the preparation as by the
    // inspection) and a 3 mm step (its walls' spans reach a travel step).
    let part = plate(|x, y| {
        Some(if x > 5.0 { 3.0 } else { 0.0 } - 0.3 * bell((x + 8.0).hypot(y - 2.0), 2.5))
    });
    let mut golden = plate(|x, _| Some(if x > 5.0 { 3.0 } else { 0.0 }));
    for j in 80..100 {
        golden.z[j * golden.width + 60] -= 3.0;
    }
    let params = DetectParams {
        travel_step_mm: Some(0.5),
        ..DetectParams::default()
    };
    let cp = CharacterizeParams::default();
    let mut rules = SurfaceRules::shipped().expect("rules");
    let raw = inspect(
        &part,
        ReferenceSource::Golden(&golden),
        &cp,
        &mut rules,
        &params,
    )
    .expect("inspect");
    let prepared = PreparedGolden::new(&golden, params.outlier_mm, cp.belt_level_mm, Some(0.5));
    let ready = inspect(
        &part,
        ReferenceSource::Prepared(&prepared),
        &cp,
        &mut rules,
        &params,
    )
    .expect("inspect");
    assert_eq!(
        raw.detection.defects.len(),
        1,
        "{:?}",
        raw.detection.defects
    );
    assert_eq!(raw.detection, ready.detection);
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert!(bits(&raw.maps.reference_mm) == bits(&ready.maps.reference_mm));
    // Prepared with another outlier limit or travel step: refused, naming it.
    for (other, what) in [
        (
            PreparedGolden::new(&golden, 2.0, cp.belt_level_mm, Some(0.5)),
            "outlier limit",
        ),
        (
            PreparedGolden::new(&golden, params.outlier_mm, cp.belt_level_mm, None),
            "travel step",
        ),
        (
            PreparedGolden::new(&golden, params.outlier_mm, 1.0, Some(0.5)),
            "belt level",
        ),
    ] {
        let e = inspect(
            &part,
            ReferenceSource::Prepared(&other),
            &cp,
            &mut rules,
            &params,
        )
        .expect_err("other parameters");
        assert!(
            matches!(
                &e,
                CoreError::Inspection(InspectionError::GoldenPreparedOtherwise { .. })
            ),
            "{e:?}"
        );
        assert!(e.to_string().contains(what), "{e}");
    }
}

#[test]
fn a_piece_of_a_dent_is_not_a_second_dent() {
    // A 6 mm dent split by a column of cells 0.3 mm too high (a wrong-index column through it): the small
    // piece right of the column lies within the large piece's footprint.
    let r = plate(|x, y| {
        let d = x.hypot(y);
        let dent = -0.3 * bell(d, 3.0);
        if (x - 1.3).abs() < 0.15 && y.abs() < 3.5 {
            Some(dent + 0.3)
        } else {
            Some(dent)
        }
    });
    let d = run(&r);
    let dents: Vec<&Defect> = d
        .defects
        .iter()
        .filter(|e| e.kind == DefectKind::Dent)
        .collect();
    assert_eq!(dents.len(), 1, "{:?}", d.defects);
    assert!(dents[0].centroid_mm[0].abs() < 0.5, "{:?}", dents[0]);
}

#[test]
fn a_channel_of_missing_data_does_not_unmake_a_hole() {
    // A 5 mm through-hole with a column of no data 0.6 mm wide running 8 mm from it (a stripe dropped for a
    // frame): the hole is still a hole, measured without the column.
    let r = plate(|x, y| {
        if x.hypot(y) < 2.5 || (x.abs() < 0.3 && y > 0.0 && y < 10.0) {
            None
        } else {
            Some(0.0)
        }
    });
    let d = run(&r);
    assert_eq!(d.defects.len(), 1, "{:?} {:?}", d.defects, d.unmeasured);
    let hole = &d.defects[0];
    assert_eq!(hole.kind, DefectKind::Hole);
    let area = std::f64::consts::PI * 2.5 * 2.5;
    assert!((hole.area_mm2 - area).abs() < 0.15 * area, "{hole:?}");
    assert!(
        hole.centroid_mm[0].hypot(hole.centroid_mm[1]) < 0.5,
        "{hole:?}"
    );
}

#[test]
fn a_seam_of_missing_samples_at_the_surfaces_height_is_not_a_hole() {
    // Three columns of no data one cell wide, 0.4 mm apart, over 1.4 mm (a stripe dropped in every other frame):
    // the measured columns between them are too thin for the part's mask, so the gap holds the surface's own
    // heights (the rules alone call it a hole, with its bottom seen 0.0002 mm deep).
    let r = plate(|x, y| {
        let column = |c: f64| (x - c).abs() < 0.1;
        if (column(0.0) || column(0.4) || column(0.8)) && y > 0.0 && y < 1.4 {
            None
        } else {
            Some(0.0)
        }
    });
    let d = run(&r);
    assert!(d.defects.is_empty(), "{:?}", d.defects);
    assert!(
        d.unmeasured.iter().any(|u| u.reason.contains("not a hole")),
        "{:?}",
        d.unmeasured
    );
}

#[test]
fn a_gap_narrower_than_the_sampling_is_unmeasured_and_a_2_mm_hole_is_a_hole() {
    // A patch without data 1.2 x 1.6 mm (a stripe's samples missing over three frames of 0.5 mm: 1.56 mm
    // equivalent diameter), and a 2 mm through-hole. With the travel step known, the patch is narrower than the
    // sampling can tell from missing samples, and the report says so; the rules alone call both holes.
    let r = plate(|x, y| {
        if (x + 8.0).abs() < 0.6 && (y - 2.0).abs() < 0.8 || (x - 8.0).hypot(y + 3.0) < 1.0 {
            None
        } else {
            Some(0.0)
        }
    });
    let maps = plane_maps(&r);
    let mut rules = SurfaceRules::shipped().expect("rules");
    let mut holes = |step: Option<f64>| {
        let params = DetectParams {
            travel_step_mm: step,
            ..DetectParams::default()
        };
        detect(&r, &maps, &mut rules, &params).expect("detect")
    };
    assert_eq!(holes(None).defects.len(), 2);
    let d = holes(Some(0.5));
    assert_eq!(d.defects.len(), 1, "{:?}", d.defects);
    let hole = &d.defects[0];
    assert_eq!(hole.kind, DefectKind::Hole);
    assert!((hole.centroid_mm[0] - 8.0).abs() < 0.3, "{hole:?}");
    let patch = d
        .unmeasured
        .iter()
        .find(|u| (u.centroid_mm[0] + 8.0).abs() < 0.5)
        .expect("the patch is reported as unmeasured");
    assert!(
        patch.reason.contains("too small to tell a hole"),
        "{}",
        patch.reason
    );
}

#[test]
fn one_frames_misplaced_samples_are_unmeasured_and_a_2_mm_bump_is_a_bump() {
    // One frame's samples 0.3 mm low over 1.2 mm of rows, filled linearly to the frames 0.5 mm before and after
    // (a triangle one step wide at half its depth), and a bump 2 mm across, 0.2 mm high (1 mm wide there).
    let r = plate(|x, y| {
        let frame = if (y - 4.0).abs() < 0.6 {
            -0.3 * (1.0 - (x + 8.0).abs() / 0.5).max(0.0)
        } else {
            0.0
        };
        Some(frame + 0.2 * bell((x - 8.0).hypot(y + 3.0), 1.0))
    });
    let maps = plane_maps(&r);
    let mut rules = SurfaceRules::shipped().expect("rules");
    let mut found = |step: Option<f64>, steps: f64| {
        let params = DetectParams {
            travel_step_mm: step,
            min_region_travel_steps: steps,
            ..DetectParams::default()
        };
        detect(&r, &maps, &mut rules, &params).expect("detect")
    };
    let kinds = |d: &Detection| d.defects.iter().map(|d| d.kind).collect::<Vec<_>>();
    let without = found(None, 1.5);
    assert_eq!(kinds(&without), [DefectKind::Dent, DefectKind::Bump]);
    assert_eq!(
        kinds(&found(Some(0.5), 0.0)),
        [DefectKind::Dent, DefectKind::Bump]
    );
    let d = found(Some(0.5), 1.5);
    assert_eq!(kinds(&d), [DefectKind::Bump], "{:?}", d.unmeasured);
    assert!((d.defects[0].centroid_mm[0] - 8.0).abs() < 0.2);
    let spike = d
        .unmeasured
        .iter()
        .find(|u| (u.centroid_mm[0] + 8.0).abs() < 0.5)
        .expect("the frame's samples are reported as unmeasured");
    assert!(
        spike.reason.contains("one frame's misplaced samples"),
        "{}",
        spike.reason
    );
    assert_eq!(d.candidates.len() + 1, without.candidates.len());
}

#[test]
fn clean_plate_has_no_defects() {
    let d = run(&plate(|_, _| Some(0.0)));
    assert!(d.defects.is_empty(), "{:?}", d.defects);
    assert!(d.warnings.is_empty(), "{:?}", d.warnings);
    assert!(d.coverage > 0.99);
}

#[test]
fn the_normal_quantile_matches_its_tables() {
    for (p, z) in [
        (0.5, 0.0),
        (0.975, 1.959_964),
        (0.8413447, 1.0),
        (0.999, 3.090_232),
        (1.0 - 1e-6, 4.753_424),
        (1e-6, -4.753_424),
        (0.025, -1.959_964),
    ] {
        assert!(
            (normal_quantile(p) - z).abs() < 1e-5,
            "{p}: {}",
            normal_quantile(p)
        );
    }
    assert_eq!(normal_quantile(0.0), f64::NEG_INFINITY);
    assert_eq!(normal_quantile(1.0), f64::INFINITY);
}

#[test]
fn a_noisy_scan_raises_its_threshold_and_says_what_it_can_see() {
    // 1 mm cells of the top each off by up to ±0.07 mm (the way a printed pattern bends frame centres), and one
    // dent 0.5 mm deep.
    let r = plate(|x, y| {
        let cell =
            ((x + 100.0).floor() as i64 * 7919 + (y + 100.0).floor() as i64 * 104_729) % 1000;
        let offset = (cell as f64 / 1000.0 - 0.5) * 0.14;
        let dent = 0.5 * bell(x.hypot(y - 2.0), 3.0);
        Some(offset - dent)
    });
    let mut rules = SurfaceRules::shipped().expect("rules");
    let maps = plane_maps(&r);
    let fixed = DetectParams {
        false_alarm: 0.0,
        ..DetectParams::default()
    };
    let blind = detect(&r, &maps, &mut rules, &fixed).expect("detect");
    assert!(blind.defects.len() > 5, "{:?}", blind.defects.len());
    let d = detect(&r, &maps, &mut rules, &DetectParams::default()).expect("detect");
    assert!(d.detectable.raised, "{:?}", d.detectable);
    assert!(d.detectable.threshold_mm > 0.1, "{:?}", d.detectable);
    assert!(
        d.warnings.iter().any(|w| w.contains("cannot be seen")),
        "{:?}",
        d.warnings
    );
    assert_eq!(d.defects.len(), 1, "{:?}", d.defects);
    assert_eq!(d.defects[0].kind, DefectKind::Dent);
    // A clean plate keeps the method's threshold.
    let clean = run(&plate(|_, _| Some(0.0)));
    assert!(!clean.detectable.raised, "{:?}", clean.detectable);
    assert_eq!(
        clean.detectable.threshold_mm,
        DetectParams::default().seed_mm
    );
    assert!(clean.detectable.noise_mm > 0.0 && clean.detectable.noise_mm < 0.005);
}

#[test]
fn bump_dent_hole_scratch_and_chip_are_found_measured_and_named() {
    let r = plate(|x, y| {
        let bump = 0.3 * bell((x + 10.0).hypot(y - 5.0), 2.5);
        let dent = -0.15 * bell((x - 8.0).hypot(y + 6.0), 1.5);
        let scratch = if (y - 8.0).abs() < 0.3 && x > 2.0 && x < 14.0 {
            -0.2
        } else {
            0.0
        };
        if (x - 0.0).hypot(y + 2.0) < 1.5 || (x - 20.0).hypot(y) < 2.0 {
            None
        } else {
            Some(bump + dent + scratch)
        }
    });
    // The chip is cut through the plate down to the belt.
    let mut r = r;
    for j in 0..r.height {
        for i in 0..r.width {
            let (x, y) = cell_xy(&r, i, j);
            if (x - 20.0).hypot(y) < 2.0 && x <= 20.0 {
                r.z[j * r.width + i] = 0.0;
            }
        }
    }
    let d = run(&r);
    let find = |k: DefectKind| {
        d.defects
            .iter()
            .find(|x| x.kind == k)
            .unwrap_or_else(|| panic!("no {k:?} in {:#?}", d.defects))
    };
    let b = find(DefectKind::Bump);
    assert!(
        (b.centroid_mm[0] + 10.0).abs() < 0.1 && (b.centroid_mm[1] - 5.0).abs() < 0.1,
        "{b:?}"
    );
    assert!((b.depth_mm - 0.3).abs() < 0.02, "{b:?}");
    let area = std::f64::consts::PI * 2.5 * 2.5;
    assert!((b.area_mm2 - area).abs() < 0.1 * area, "{b:?}");
    let dent = find(DefectKind::Dent);
    assert!(
        (dent.depth_mm - 0.15).abs() < 0.02 && (dent.centroid_mm[0] - 8.0).abs() < 0.1,
        "{dent:?}"
    );
    let hole = find(DefectKind::Hole);
    assert!(
        (hole.depth_mm - 10.0).abs() < 0.05 && !hole.bottom_seen,
        "{hole:?}"
    );
    assert!(
        (hole.area_mm2 - std::f64::consts::PI * 2.25).abs() < 0.2 * 7.07,
        "{hole:?}"
    );
    let s = find(DefectKind::Scratch);
    assert!(s.bbox_mm[2] - s.bbox_mm[0] > 10.0, "{s:?}");
    let c = find(DefectKind::EdgeChip);
    assert!((c.centroid_mm[0] - 19.2).abs() < 0.5, "{c:?}");
    assert_eq!(d.defects.len(), 5, "{:#?}", d.defects);
}

#[test]
fn empty_scans_and_parts_out_of_view_are_reported() {
    let empty = RangeImage {
        origin_mm: [0.0, 0.0],
        spacing_mm: [0.2, 0.2],
        width: 10,
        height: 10,
        z: vec![f32::NAN; 100],
        intensity: None,
    };
    let p = CharacterizeParams::default();
    assert!(matches!(
        fit_reference(&empty, &p),
        Err(CoreError::Inspection(InspectionError::TooFewPartCells {
            part_cells: 0,
            cells: 100,
            ..
        }))
    ));
    let maps = surface_maps(&empty, vec![0.0; 100], &p).expect("maps");
    let mut rules = SurfaceRules::shipped().expect("rules");
    let e = detect(&empty, &maps, &mut rules, &DetectParams::default()).expect_err("no part");
    assert_eq!(e, CoreError::Inspection(InspectionError::NoPart));
    assert!(e.to_string().contains("no part"), "{e}");
    // A plate running off the top of the grid.
    let mut r = plate(|_, _| Some(0.0));
    for i in 0..r.width {
        let (x, _) = cell_xy(&r, i, 0);
        if x.abs() < 20.0 {
            for j in 0..30 {
                r.z[j * r.width + i] = 10.0;
            }
        }
    }
    let d = run(&r);
    assert!(
        d.warnings.iter().any(|w| w.contains("top")),
        "{:?}",
        d.warnings
    );
}

/// Naive dilation (grow) or erosion over a (2r+1)² window clipped to the grid.
fn naive(w: usize, h: usize, m: &[bool], r: usize, grow: bool) -> Vec<bool> {
    (0..w * h)
        .map(|k| {
            let (i, j) = (k % w, k / w);
            let hit = (j.saturating_sub(r)..(j + r + 1).min(h)).any(|jj| {
                (i.saturating_sub(r)..(i + r + 1).min(w)).any(|ii| m[jj * w + ii] == grow)
            });
            if hit { grow } else { !grow }
        })
        .collect()
}

proptest::proptest! {
    #[test]
    fn separable_morphology_matches_the_naive_window(
        w in 1usize..140, h in 1usize..8, r in 1usize..4, grow: bool, bits in proptest::collection::vec(proptest::bool::ANY, 1120)
    ) {
        let m = &bits[..w * h];
        proptest::prop_assert_eq!(morph(w, h, m, r, grow), naive(w, h, m, r, grow));
        // Closing and opening are the two compositions.
        proptest::prop_assert_eq!(
            closing(w, h, m, r),
            naive(w, h, &naive(w, h, m, r, true), r, false)
        );
        proptest::prop_assert_eq!(opening(w, h, m), naive(w, h, &naive(w, h, m, 1, false), 1, true));
    }

    #[test]
    fn chamfer_distance_is_within_8_percent_of_euclidean(
        w in 2usize..15, h in 2usize..15, seeds in proptest::collection::vec((0usize..15, 0usize..15), 1..4)
    ) {
        let pts: Vec<(usize, usize)> = seeds.iter().map(|&(i, j)| (i % w, j % h)).collect();
        let d = distance_to(w, h, |k| pts.contains(&(k % w, k / w)));
        for (k, &dk) in d.iter().enumerate() {
            let (i, j) = ((k % w) as f64, (k / w) as f64);
            let e = pts.iter().map(|&(a, b)| (i - a as f64).hypot(j - b as f64)).fold(f64::INFINITY, f64::min);
            proptest::prop_assert!((f64::from(dk) - e).abs() <= 0.09 * e + 1e-6, "{dk} vs {e}");
        }
    }
}

#[test]
fn kinds_round_trip_by_name() {
    for k in DefectKind::ALL {
        assert_eq!(DefectKind::from_name(k.name()), Some(k));
    }
}
