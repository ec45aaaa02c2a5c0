//! Characterization on synthetic range images: references fitted through defects and steps, registration of
//! shifted golden scans, derivatives of known surfaces.

use super::*;

proptest::proptest! {
    /// The separable 3 x 3 smoothing equals the direct window mean.
    #[test]
    fn separable_smoothing_equals_the_window_mean(
        w in 1usize..12,
        h in 1usize..12,
        vals in proptest::collection::vec(proptest::option::of(-1.0f32..1.0), 144),
    ) {
        let v: Vec<f32> = (0..w * h).map(|k| vals[k].unwrap_or(f32::NAN)).collect();
        let fast = smooth3(w, h, &v);
        for j in 0..h {
            for i in 0..w {
                let (mut s, mut c) = (0.0f32, 0u32);
                for jj in j.saturating_sub(1)..(j + 2).min(h) {
                    for ii in i.saturating_sub(1)..(i + 2).min(w) {
                        if v[jj * w + ii].is_finite() {
                            s += v[jj * w + ii];
                            c += 1;
                        }
                    }
                }
                let want = if c >= 5 && v[j * w + i].is_finite() { s / c as f32 } else { f32::NAN };
                let got = fast[j * w + i];
                proptest::prop_assert!(
                    (want.is_nan() && got.is_nan()) || (want - got).abs() < 1e-5,
                    "({}, {}): {} vs {}", i, j, got, want
                );
            }
        }
    }
}

/// A range image of `f` on a `w` x `h` grid of 0.2 mm cells starting at (−w/10, h/10).
fn image(w: usize, h: usize, f: impl Fn(f64, f64) -> f64) -> RangeImage {
    let mut r = RangeImage {
        origin_mm: [-(w as f64) * 0.1, h as f64 * 0.1],
        spacing_mm: [0.2, 0.2],
        width: w,
        height: h,
        z: vec![0.0; w * h],
        intensity: None,
    };
    for j in 0..h {
        for i in 0..w {
            let (x, y) = cell_xy(&r, i, j);
            r.z[j * w + i] = f(x, y) as f32;
        }
    }
    r
}

/// The registration that maps every point onto itself.
const IDENTITY: Registration = Registration {
    dx_mm: 0.0,
    dy_mm: 0.0,
    theta_rad: 0.0,
    dz_mm: 0.0,
    centre_mm: [0.0, 0.0],
    mean_difference_mm: 0.0,
    overlap: 1.0,
};

#[test]
fn a_golden_wall_reaches_a_travel_step_along_x() {
    // A step from 10 to 17 mm at x = 0 in the golden scan; the scan sees it 0.5 mm further along x (its last
    // sample before the step fell a whole 0.5 mm travel step short of it), and has a 0.2 mm dent 3 mm away.
    let golden = image(100, 60, |x, _| if x > 0.0 { 17.0 } else { 10.0 });
    let scan = image(100, 60, |x, _| {
        if x > 0.5 {
            17.0
        } else if (x + 3.0).abs() < 0.5 {
            9.8
        } else {
            10.0
        }
    });
    let worst = |step: Option<f64>| {
        let reference = IDENTITY.heights(&scan, &golden, 0.5, step);
        let mut worst = 0.0f64;
        for (k, (&z, &r)) in scan.z.iter().zip(&reference).enumerate() {
            let x = cell_xy(&scan, k % scan.width, k / scan.width).0;
            if x.abs() < 1.0 && r.is_finite() {
                worst = worst.max(f64::from((z - r).abs()));
            }
        }
        let dent = scan.width * 30 + 35; // x = -3
        (worst, f64::from(scan.z[dent] - reference[dent]))
    };
    let (one_cell, dent) = worst(None);
    assert!(one_cell > 6.0, "{one_cell}: the wall a cell's reach misses");
    assert!((dent + 0.2).abs() < 1e-3, "{dent}");
    let (a_step, dent) = worst(Some(0.5));
    assert!(a_step < 1e-3, "{a_step}");
    assert!((dent + 0.2).abs() < 1e-3, "{dent}");
}

#[test]
fn a_golden_wall_is_compared_within_its_span_and_flat_ground_as_it_is() {
    // A boss 8 mm high on a 10 mm plate; the scan sees it 0.1 mm (half a cell) further along x, and has a dent
    // 0.4 mm deep on the plate away from it.
    let boss = |x: f64, y: f64| if x.hypot(y) < 5.0 { 18.0 } else { 10.0 };
    let golden = image(100, 100, boss);
    let scan = image(100, 100, |x, y| {
        let d = (x - 6.5).hypot(y + 6.5);
        boss(x - 0.1, y) - if d < 1.5 { 0.4 * (1.0 - d / 1.5) } else { 0.0 }
    });
    let reference = IDENTITY.heights(&scan, &golden, 0.5, None);
    let (mut plain_max, mut wall_max) = (0.0f64, 0.0f64);
    for j in 0..scan.height {
        for i in 0..scan.width {
            let (x, y) = cell_xy(&scan, i, j);
            let k = j * scan.width + i;
            let z = f64::from(scan.z[k]);
            if (x.hypot(y) - 5.0).abs() < 0.5 {
                let plain = bilinear_above(&golden, x, y, 0.5).expect("golden");
                plain_max = plain_max.max((z - plain).abs());
                wall_max = wall_max.max((z - f64::from(reference[k])).abs());
            }
        }
    }
    assert!(
        plain_max > 5.0,
        "cell by cell the rim is millimetres off: {plain_max}"
    );
    assert!(
        wall_max < 1e-6,
        "within the wall's span it is not: {wall_max}"
    );
    // The dent keeps its depth.
    let (i, j) = (
        ((6.5 - scan.origin_mm[0]) / 0.2).round() as usize,
        ((scan.origin_mm[1] + 6.5) / 0.2).round() as usize,
    );
    let k = j * scan.width + i;
    let dev = f64::from(scan.z[k] - reference[k]);
    assert!((dev + 0.4).abs() < 0.06, "{dev}");
}

#[test]
fn the_span_map_is_the_span_of_every_point() {
    // Steps, a hole (NaN) and belt cells (below the floor), at points inside and off the grid.
    let r = image(37, 23, |x, y| {
        if x.hypot(y) < 0.7 {
            f64::NAN
        } else if x < -2.0 {
            0.1
        } else {
            10.0 + (3.0 * x).sin() + if y > 1.0 { 2.0 } else { 0.0 }
        }
    });
    // The usual window and wider ones (three cells along x: a 0.5 mm travel step on a 0.2 mm grid).
    for reach in [1, 2, 3, 5] {
        let spans = SpanMap::new(&r, 0.5, reach);
        let mut rng = 12345u64;
        for _ in 0..2000 {
            rng = rng
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let x = ((rng >> 11) % 10_000) as f64 / 10_000.0 * 9.0 - 4.5;
            let y = ((rng >> 35) % 10_000) as f64 / 10_000.0 * 6.0 - 3.0;
            let (fi, fj) = grid_coords(&r, x, y);
            let want = local_span(&r, fi, fj, 0.5, reach).map(|(a, b)| (a as f32, b as f32));
            let got = spans.at(&r, fi, fj).map(|(a, b)| (a as f32, b as f32));
            assert_eq!(got, want, "reach {reach} at ({x}, {y})");
        }
    }
    assert_eq!(wall_reach_cells(&r, Some(0.5)), 3);
    assert_eq!(wall_reach_cells(&r, None), 1);
    assert_eq!(wall_reach_cells(&r, Some(0.1)), 1);
}

#[test]
fn a_golden_slope_seen_slightly_misregistered_does_not_deviate_but_a_dent_does() {
    // A 10 mm plate whose edge x < -5 is a chamfer of slope 0.6 down to 8.5 mm (a span of 0.48 mm over the
    // wall band's four cells: not a wall). The scan is registered 0.1 mm off along x and has a dent 0.2 mm deep
    // on the plate.
    let part = |x: f64| {
        if x < -5.0 {
            (10.0 + 0.6 * (x + 5.0)).max(8.5)
        } else {
            10.0
        }
    };
    let golden = image(100, 100, |x, _| part(x));
    let scan = image(100, 100, |x, y| {
        let d = (x - 5.0).hypot(y);
        part(x - 0.1) - if d < 2.0 { 0.2 * (1.0 - d / 2.0) } else { 0.0 }
    });
    let reference = IDENTITY.heights(&scan, &golden, 0.5, None);
    let mut chamfer_max = 0.0f64;
    let mut dent_min = 0.0f64;
    for j in 0..scan.height {
        for i in 0..scan.width {
            let (x, y) = cell_xy(&scan, i, j);
            let k = j * scan.width + i;
            let dev = f64::from(scan.z[k] - reference[k]);
            if (-7.0..-5.5).contains(&x) && y.abs() < 8.0 {
                chamfer_max = chamfer_max.max(dev.abs());
            }
            if (x - 5.0).hypot(y) < 0.3 {
                dent_min = dent_min.min(dev);
            }
        }
    }
    // Compared cell by cell the chamfer is 0.06 mm off everywhere (more than a small defect's threshold).
    assert!(chamfer_max < 1e-6, "chamfer deviates by {chamfer_max}");
    assert!(dent_min < -0.15, "the dent is {dent_min} deep");
}

#[test]
fn robust_fit_ignores_defects_steps_and_belt() {
    // A tilted 10 mm plate with a 3 mm step on a quarter of it and a dent, on the belt.
    let r = image(300, 200, |x, y| {
        if x.abs() > 25.0 || y.abs() > 17.0 {
            0.0
        } else if x > 10.0 && y > 5.0 {
            13.0 + 0.01 * x
        } else if (x + 5.0).hypot(y) < 3.0 {
            9.5 + 0.01 * x
        } else {
            10.0 + 0.01 * x - 0.005 * y
        }
    });
    let f = fit_reference(&r, &CharacterizeParams::default()).expect("fit");
    assert!((f.height(0.0, 0.0) - 10.0).abs() < 1e-3, "{f:?}");
    assert!((f.height(10.0, -10.0) - 10.15).abs() < 1e-3, "{f:?}");
    let q = fit_reference(
        &r,
        &CharacterizeParams {
            shape: ReferenceShape::Quadratic,
            ..CharacterizeParams::default()
        },
    )
    .expect("fit");
    assert!((q.height(-20.0, -15.0) - (10.0 - 0.2 + 0.075)).abs() < 1e-3);
    let empty = image(10, 10, |_, _| 0.0);
    let e = fit_reference(&empty, &CharacterizeParams::default()).expect_err("belt only");
    assert!(e.to_string().contains("no part"), "{e}");
}

#[test]
fn curvature_and_normals_match_a_sphere_and_stop_at_holes() {
    // A sphere cap of radius 50 mm: mean curvature 1/50, Gaussian 1/2500, normals radial.
    let rad = 50.0;
    let mut r = image(100, 100, |x, y| {
        10.0 + (rad * rad - x * x - y * y).sqrt() - rad
    });
    // A hole at the centre.
    for j in 45..55 {
        for i in 45..55 {
            r.z[j * 100 + i] = f32::NAN;
        }
    }
    let refh = vec![10.0f32; 100 * 100];
    let maps = surface_maps(&r, refh, &CharacterizeParams::default()).expect("maps");
    let m = derivative_maps(&r, &maps);
    let k = 20 * 100 + 70; // x = 4, y = 6
    // One cell at a time gives the same.
    let g = geometry_at(&r, &maps, 70, 20).expect("complete window");
    assert!((g.mean_curvature - f64::from(m.mean_curvature[k])).abs() < 1e-5);
    assert!(geometry_at(&r, &maps, 43, 50).is_none());
    let (x, y) = cell_xy(&r, 70, 20);
    assert!(
        (f64::from(m.mean_curvature[k]) - 1.0 / rad).abs() < 1e-3,
        "{}",
        m.mean_curvature[k]
    );
    assert!((f64::from(m.gaussian_curvature[k]) - 1.0 / (rad * rad)).abs() < 1e-4);
    let n = m.normal[k];
    let zc = (rad * rad - x * x - y * y).sqrt();
    assert!((f64::from(n[0]) - x / rad).abs() < 1e-3 && (f64::from(n[1]) - y / rad).abs() < 1e-3);
    assert!((f64::from(n[2]) - zc / rad).abs() < 1e-3);
    // Next to the hole: no value (the window would cross it); inside: no deviation either.
    assert!(m.mean_curvature[50 * 100 + 43].is_nan());
    assert!(maps.deviation_mm[50 * 100 + 50].is_nan());
    assert!(m.mean_curvature[50 * 100 + 40].is_finite());
}

/// [`remove_outliers`] as first written: the neighbour test cell by cell.
fn remove_outliers_cell_by_cell(range: &mut RangeImage, limit_mm: f64) -> usize {
    let (w, h) = (range.width, range.height);
    let limit = limit_mm as f32;
    let z = range.z.clone();
    let mut removed = 0;
    for j in 0..h {
        for i in 0..w {
            let k = j * w + i;
            let v = z[k];
            if !v.is_finite() {
                continue;
            }
            let differs = |n: f32| n.is_finite() && (n - v).abs() > limit;
            let rough = (i > 0 && differs(z[k - 1]))
                || (i + 1 < w && differs(z[k + 1]))
                || (j > 0 && differs(z[k - w]))
                || (j + 1 < h && differs(z[k + w]));
            if !rough {
                continue;
            }
            let mut window = Vec::new();
            for jj in j.saturating_sub(2)..(j + 3).min(h) {
                for ii in i.saturating_sub(2)..(i + 3).min(w) {
                    if z[jj * w + ii].is_finite() {
                        window.push(z[jj * w + ii]);
                    }
                }
            }
            if window.len() < 9 {
                continue;
            }
            let mid = window.len() / 2;
            let m = *window.select_nth_unstable_by(mid, f32::total_cmp).1;
            let agree = window.iter().filter(|&&n| (n - m).abs() <= limit).count();
            if (v - m).abs() > limit && 3 * agree >= 2 * window.len() {
                range.z[k] = f32::NAN;
                removed += 1;
            }
        }
    }
    removed
}

#[test]
fn outliers_are_the_ones_the_cell_by_cell_test_finds() {
    // Steps, holes, infinities, spikes and lone cells, on images down to one cell wide.
    let mut rng = 99u64;
    let mut next = move || {
        rng = rng
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (rng >> 33) as u32
    };
    for (w, h) in [
        (0, 4),
        (4, 0),
        (1, 7),
        (7, 1),
        (2, 2),
        (3, 11),
        (13, 9),
        (40, 31),
    ] {
        for _ in 0..20 {
            let z: Vec<f32> = (0..w * h)
                .map(|k| match next() % 20 {
                    0 => f32::NAN,
                    1 => 14.0,
                    2 => f32::INFINITY,
                    3 => 10.0 + (next() % 100) as f32 * 0.05,
                    _ => 10.0 + (k % w) as f32 * 0.01 + if k % w > w / 2 { 2.0 } else { 0.0 },
                })
                .collect();
            let r = RangeImage {
                origin_mm: [0.0, 0.0],
                spacing_mm: [0.1, 0.1],
                width: w,
                height: h,
                z,
                intensity: None,
            };
            let (mut fast, mut plain) = (r.clone(), r.clone());
            let n = remove_outliers(&mut fast, 1.0);
            assert_eq!(n, remove_outliers_cell_by_cell(&mut plain, 1.0));
            let bits = |r: &RangeImage| r.z.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&fast), bits(&plain), "{w}x{h}");
        }
    }
}

/// The registration tests' part: a 30 x 20 mm plate with a hole and a 4 mm step in one corner; `top` is the
/// height of the rest of its top at (x, y).
fn stepped_plate(x: f64, y: f64, top: impl Fn(f64, f64) -> f64) -> f64 {
    if x.abs() > 15.0 || y.abs() > 10.0 || (x - 5.0).hypot(y - 3.0) < 2.0 {
        0.0
    } else if x < -5.0 && y > 0.0 {
        14.0
    } else {
        top(x, y)
    }
}

#[test]
fn the_coarse_searchs_shortlist_picks_what_the_full_search_picks() {
    // A gentle tilt and some deterministic roughness on the top, so that the costs are not flat.
    let part = |x: f64, y: f64| {
        stepped_plate(x, y, |x, y| {
            10.0 + 0.02 * x + 0.01 * ((7.0 * x).sin() * (5.0 * y).cos())
        })
    };
    let golden = image(200, 150, part);
    let params = RegisterParams::default();
    let mut scratch = Vec::new();
    for (dx, dy, th) in [
        (1.3, -0.7, 0.02),
        (-3.6, 2.4, -0.015),
        (4.4, 3.8, 0.004),
        (-0.4, 4.9, 0.0),
    ] {
        let scan = image(200, 150, |x, y| {
            let (c, s) = (f64::cos(th), f64::sin(th));
            part(c * x - s * y + dx, s * x + c * y + dy)
        });
        let cells: Vec<(f64, f64, f64)> = (0..scan.z.len())
            .filter(|&k| f64::from(scan.z[k]) > params.belt_level_mm)
            .map(|k| {
                let (x, y) = cell_xy(&scan, k % scan.width, k / scan.width);
                (x, y, f64::from(scan.z[k]))
            })
            .collect();
        let n = cells.len() as f64;
        let centre = [
            cells.iter().map(|c| c.0).sum::<f64>() / n,
            cells.iter().map(|c| c.1).sum::<f64>() / n,
        ];
        let sample: Vec<(f64, f64, f64)> = cells
            .iter()
            .step_by(cells.len() / 1500)
            .map(|&(x, y, z)| (x - centre[0], y - centre[1], z))
            .collect();
        // The centroids' match, here off by the move (the golden part's centroid is near the origin).
        let start = Registration {
            dx_mm: -centre[0],
            dy_mm: -centre[1],
            theta_rad: 0.0,
            dz_mm: 0.0,
            centre_mm: centre,
            mean_difference_mm: f64::NAN,
            overlap: 0.0,
        };
        let short = coarse_search(
            &golden,
            &sample,
            start,
            &params,
            COARSE_SHORTLIST,
            &mut scratch,
        );
        let full = coarse_search(&golden, &sample, start, &params, usize::MAX, &mut scratch);
        assert_eq!(
            (short.dx_mm, short.dy_mm, short.theta_rad),
            (full.dx_mm, full.dy_mm, full.theta_rad)
        );
        // And it lands within a step of the move: the coarse search is not idle here.
        let (gx, gy) = short.map(centre[0], centre[1]);
        let (ex, ey) = (
            th.cos() * centre[0] - th.sin() * centre[1] + dx,
            th.sin() * centre[0] + th.cos() * centre[1] + dy,
        );
        assert!(
            (gx - ex).abs() <= 0.75 && (gy - ey).abs() <= 0.75,
            "{dx} {dy}: {short:?}"
        );
    }
}

#[test]
fn registration_recovers_a_shift_rotation_and_height() {
    let part = |x: f64, y: f64| stepped_plate(x, y, |_, _| 10.0);
    let golden = image(200, 150, part);
    let moves: [(f64, f64, f64, f64); 2] = [(1.3, -0.7, 0.02, 0.05), (-3.6, 2.4, -0.015, -0.2)];
    let mut scan = golden.clone();
    for (dx, dy, th, dz) in moves {
        // The scan: the golden part moved; scan point p sits at R p + t on the golden part.
        scan = image(200, 150, |x, y| {
            let (c, s) = (th.cos(), th.sin());
            let (gx, gy) = (c * x - s * y + dx, s * x + c * y + dy);
            let z = part(gx, gy);
            if z > 0.0 { z + dz } else { 0.0 }
        });
        let reg = register(&scan, &golden, &RegisterParams::default()).expect("register");
        // The centre of rotation is the scan part's centroid: compare mapped points instead of raw parameters.
        for (x, y) in [(0.0, 0.0), (10.0, 5.0), (-10.0, -5.0)] {
            let (gx, gy) = reg.map(x, y);
            let (c, s) = (th.cos(), th.sin());
            let (ex, ey) = (c * x - s * y + dx, s * x + c * y + dy);
            assert!(
                (gx - ex).abs() < 0.05 && (gy - ey).abs() < 0.05,
                "{dx} {dy} {th}: {reg:?}"
            );
        }
        assert!((reg.dz_mm - dz).abs() < 0.01);
    }
    // Another product: a small block the scan's part cannot lie on.
    let other = image(200, 150, |x, y| {
        if x.abs() < 4.0 && y.abs() < 4.0 {
            10.0
        } else {
            0.0
        }
    });
    let e = register(&scan, &other, &RegisterParams::default()).expect_err("no overlap");
    assert!(e.to_string().contains("does not overlap"), "{e}");
}
