//! Extraction end to end on synthetic lines and frames: dim and bright stripes, cut profiles, shoulders, axes,
//! thresholds, sizes and policies.

use super::*;
use crate::image::Image;

fn two_stripes(width: usize, height: usize, a: f64, b: f64, slope: f64) -> Image<u8> {
    let mut img = Image::<u8>::new(width, height);
    for y in 0..height {
        for x in 0..width {
            let mut v = 8.0;
            for (c, amp) in [(a + slope * y as f64, 180.0), (b, 120.0)] {
                v += amp * (-0.5 * ((x as f64 - c) / 1.5).powi(2)).exp();
            }
            img.data_mut()[y * width + x] = v.round() as u8;
        }
    }
    img
}

#[test]
fn every_method_finds_both_stripes_on_every_row() {
    let img = two_stripes(120, 40, 30.3, 80.6, 0.05);
    for m in Method::ALL {
        let params = ExtractParams {
            method: m,
            ..ExtractParams::default()
        };
        let got = extract(img.view(), &params).expect("extract");
        if m == Method::Com {
            assert_eq!(got.points.len(), 40, "one point per line");
            continue;
        }
        if got.points.len() != 80 {
            let rows: Vec<_> = got.points.iter().map(|p| (p.row, p.x)).collect();
            panic!("{}: {} points {rows:?}", m.name(), got.points.len());
        }
        for p in &got.points {
            let expected = if p.x < 55.0 {
                30.3 + 0.05 * f64::from(p.row)
            } else {
                80.6
            };
            // The three-point centre of mass is known to be biased by up to 0.36 px at this width.
            let tol = if m == Method::Com3 { 0.45 } else { 0.12 };
            assert!(
                (p.x - expected).abs() < tol,
                "{}: row {} x {} vs {expected}",
                m.name(),
                p.row,
                p.x
            );
        }
        assert!(got.empty_lines().is_empty());
    }
}

#[test]
fn the_stripes_width_in_integers_is_the_floating_point_width() {
    fn plain<T: Pixel>(line: &[T], p: &Peak, bg: f64) -> f64 {
        let (mut s0, mut s1, mut s2) = (0.0, 0.0, 0.0);
        for (i, q) in line
            .iter()
            .enumerate()
            .take(p.roi_right + 1)
            .skip(p.roi_left)
        {
            let w = (f64::from(q.to_f32()) - bg).max(0.0);
            s0 += w;
            s1 += w * i as f64;
            s2 += w * i as f64 * i as f64;
        }
        if s0 <= 0.0 {
            return 1.0;
        }
        let m = s1 / s0;
        (s2 / s0 - m * m).max(0.0).sqrt()
    }
    let mut rng = 7u32;
    let mut next = || {
        rng = rng.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        rng >> 8
    };
    for case in 0..2000 {
        // Long 16-bit lines with wide regions reach sums past 2^53 (the floating-point path).
        let n = if case % 10 == 0 { 60_000 } else { 700 };
        let line: Vec<u16> = (0..n).map(|_| (next() % 65_536) as u16).collect();
        let lo = next() as usize % (n - 1);
        let hi = (lo + 1 + next() as usize % 4_000).min(n - 1);
        let p = Peak {
            top_start: lo,
            top_end: lo,
            value: 0,
            roi_left: lo,
            roi_right: hi,
        };
        for bg in [0.0, f64::from(next() % 65_536), 100.5, -3.0] {
            assert_eq!(
                stripe_sigma(&line, &p, bg).to_bits(),
                plain(&line, &p, bg).to_bits(),
                "case {case}, bg {bg}"
            );
        }
        let line8: Vec<u8> = line.iter().map(|&v| (v >> 8) as u8).collect();
        let bg = f64::from(next() % 256);
        assert_eq!(
            stripe_sigma(&line8, &p, bg).to_bits(),
            plain(&line8, &p, bg).to_bits()
        );
    }
}

#[test]
fn a_dim_shoulder_beside_a_bright_stripe_is_marked_cut() {
    // A stripe split by an edge: a bright peak at 30 and a dim one 5 px away (a sheet across a chamfer); a
    // stripe of the same brightness 5 px from another is not a shoulder.
    let line = |peaks: &[(f64, f64)]| -> Image<u8> {
        let mut img = Image::<u8>::new(80, 4);
        for y in 0..4 {
            for x in 0..80 {
                let v: f64 = 8.0
                    + peaks
                        .iter()
                        .map(|&(c, a)| a * (-0.5 * ((x as f64 - c) / 1.0).powi(2)).exp())
                        .sum::<f64>();
                img.data_mut()[y * 80 + x] = v.round() as u8;
            }
        }
        img
    };
    // Four scan lines, each read alone: no line linking.
    let params = ExtractParams {
        method: Method::Linear,
        along_lines: 0,
        lines: None,
        ..ExtractParams::default()
    };
    let got = extract(line(&[(30.0, 160.0), (35.0, 40.0)]).view(), &params).expect("extract");
    assert_eq!(got.points.len(), 8, "{:?}", got.points);
    for p in &got.points {
        assert_eq!(p.cut, p.x > 32.5, "{p:?}");
    }
    let got = extract(line(&[(30.0, 150.0), (35.0, 130.0)]).view(), &params).expect("extract");
    assert_eq!(got.points.len(), 8, "{:?}", got.points);
    assert!(got.points.iter().all(|p| !p.cut), "{:?}", got.points);
}

#[test]
fn columns_axis_and_policies() {
    let img = two_stripes(120, 40, 30.3, 80.6, 0.0);
    // Transpose into a column image.
    let mut t = Image::<u8>::new(40, 120);
    for y in 0..40 {
        for x in 0..120 {
            t.data_mut()[x * 40 + y] = img.data()[y * 120 + x];
        }
    }
    let cols = extract(
        t.view(),
        &ExtractParams {
            axis: Axis::Columns,
            ..ExtractParams::default()
        },
    )
    .expect("extract");
    assert_eq!(cols.points.len(), 80);
    assert_eq!(cols.lines, 40);
    for (policy, x) in [
        (Policy::Brightest, 30.3),
        (Policy::First, 30.3),
        (Policy::Last, 80.6),
        (Policy::Continuity, 30.3),
    ] {
        let got = extract(
            img.view(),
            &ExtractParams {
                policy,
                ..ExtractParams::default()
            },
        )
        .expect("extract");
        assert_eq!(got.points.len(), 40, "{policy:?}");
        assert!(
            got.points.iter().all(|p| (p.x - x).abs() < 0.1),
            "{policy:?}"
        );
    }
}

#[test]
fn empty_and_saturated_frames_give_no_points() {
    let dark = Image::<u8>::new(50, 10);
    let got = extract(dark.view(), &ExtractParams::default()).expect("extract");
    assert!(got.points.is_empty());
    assert_eq!(got.empty_lines().len(), 10);
    let bright = Image::<u16>::from_vec(50, 10, vec![65535; 500]).expect("img");
    assert!(
        extract(bright.view(), &ExtractParams::default())
            .expect("extract")
            .points
            .is_empty()
    );
    let tiny = Image::<u8>::new(0, 0);
    assert!(
        extract(tiny.view(), &ExtractParams::default())
            .expect("extract")
            .points
            .is_empty()
    );
}

#[test]
fn per_line_thresholds_follow_each_lines_noise() {
    // Noisy upper half (0 to 31 grey levels), clean lower half, one stripe everywhere.
    let (w, h) = (80usize, 40usize);
    let mut img = Image::<u8>::new(w, h);
    let mut rng = 7u32;
    for y in 0..h {
        for x in 0..w {
            rng = rng.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            let noise = if y < 20 {
                f64::from(rng >> 27)
            } else {
                f64::from(rng >> 31)
            };
            let v = 20.0 + noise + 200.0 * (-0.5 * ((x as f64 - 40.3) / 1.5).powi(2)).exp();
            img.data_mut()[y * w + x] = v.min(255.0) as u8;
        }
    }
    let line = extract(
        img.view(),
        &ExtractParams {
            method: Method::Gaussian,
            threshold: Threshold::Line,
            along_lines: 0,
            lines: None,
            ..ExtractParams::default()
        },
    )
    .expect("extract");
    if line.points.len() != h {
        let rows: Vec<_> = line.points.iter().map(|p| (p.row, p.x)).collect();
        panic!("one stripe per line: {rows:?}");
    }
    assert!(line.points.iter().all(|p| (p.x - 40.3).abs() < 0.5));
    let per_row = ExtractParams {
        threshold: Threshold::Fixed(8.0),
        along_lines: 0,
        lines: None,
        ..ExtractParams::default()
    };
    let frame = extract(img.view(), &per_row).expect("extract");
    assert!(
        frame.points.len() > h,
        "a threshold below the noisy lines' noise finds noise peaks there, read line by line"
    );
    // The same threshold with the evidence of the line (the sum along it, the links between lines) does not.
    let linked = ExtractParams {
        threshold: Threshold::Fixed(8.0),
        ..ExtractParams::default()
    };
    let frame = extract(img.view(), &linked).expect("extract");
    assert_eq!(frame.points.len(), h, "{:?}", frame.points);
}

#[test]
fn the_edge_of_a_bright_noisy_surface_is_no_stripe() {
    // A plate lit by ambient light (40 levels, noise of 8) on a dark belt (10, noise of 2), its sides at columns 60
    // and 160 running down every row, and one stripe on the plate at 110.3. Only the stripe is a peak: at the
    // plate's sides the light falls far on one side only.
    let (w, h) = (220usize, 120usize);
    let mut img = Image::<u16>::new(w, h);
    let mut rng = 11u64;
    for y in 0..h {
        for x in 0..w {
            let mut noise = 0.0;
            for _ in 0..4 {
                rng = rng
                    .wrapping_mul(6_364_136_223_846_793_005)
                    .wrapping_add(1_442_695_040_888_963_407);
                noise += (rng >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
            }
            // The optics blur the sides: a logistic edge about 1.2 px wide.
            let edge = |t: f64| 1.0 / (1.0 + (-1.4 * t).exp());
            let plate = edge(x as f64 - 60.0) * edge(160.0 - x as f64);
            let (base, sigma) = (10.0 + 30.0 * plate, 2.0 + 6.0 * plate);
            let stripe = 600.0 * (-0.5 * ((x as f64 - 110.3) / 1.5).powi(2)).exp();
            let v = base + stripe + sigma * noise * 3.0f64.sqrt();
            img.data_mut()[y * w + x] = v.round().clamp(0.0, 4095.0) as u16;
        }
    }
    let params = ExtractParams {
        threshold: Threshold::Local,
        ..ExtractParams::default()
    };
    let found = extract(img.view(), &params).expect("extract");
    let stray: Vec<_> = found
        .points
        .iter()
        .filter(|p| (p.x - 110.3).abs() > 1.5)
        .map(|p| (p.row, p.x))
        .collect();
    assert!(stray.is_empty(), "points off the stripe: {stray:?}");
    assert!(found.points.len() >= h - 2, "{} points", found.points.len());
}

#[test]
fn noise_the_camera_correlates_over_neighbouring_pixels_is_measured_whole() {
    // Demosaicing and compression spread each pixel's noise over its neighbours: white noise averaged over 3 x 3
    // pixels, 100 +- 6 levels, and one stripe at 60.3. A first difference reads such noise several times low,
    // and its chance peaks then chain into lines.
    let (w, h) = (160usize, 160usize);
    let mut rng = 5u64;
    let mut white = vec![0.0f64; w * h];
    for v in white.iter_mut() {
        rng = rng
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        *v = (rng >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
    }
    let mut img = Image::<u16>::new(w, h);
    for y in 0..h {
        for x in 0..w {
            let mut n = 0.0;
            for dy in [-1isize, 0, 1] {
                for dx in [-1isize, 0, 1] {
                    let (xx, yy) = (
                        (x as isize + dx).clamp(0, w as isize - 1),
                        (y as isize + dy).clamp(0, h as isize - 1),
                    );
                    n += white[yy as usize * w + xx as usize];
                }
            }
            // Uniform noise of unit variance is 12^0.5 wide; nine of them averaged have a ninth of it.
            let noise = 6.0 * 3.0 * n * 12f64.sqrt() / 9.0;
            let stripe = 300.0 * (-0.5 * ((x as f64 - 60.3) / 1.5).powi(2)).exp();
            img.data_mut()[y * w + x] = (100.0 + noise + stripe).round() as u16;
        }
    }
    let params = ExtractParams {
        threshold: Threshold::Local,
        ..ExtractParams::default()
    };
    let found = extract(img.view(), &params).expect("extract");
    let stray = found
        .points
        .iter()
        .filter(|p| (p.x - 60.3).abs() > 1.5)
        .count();
    assert!(stray <= 2, "{stray} points off the stripe");
    assert!(found.points.len() >= h - 2, "{} points", found.points.len());
}

#[test]
fn fuzzy_drops_short_noise_segments() {
    let mut img = two_stripes(120, 60, 30.3, 80.6, 0.05);
    // Two isolated specks: short segments the detector must drop.
    img.data_mut()[10 * 120 + 55] = 200;
    img.data_mut()[40 * 120 + 60] = 200;
    let params = ExtractParams {
        method: Method::Fuzzy,
        ..ExtractParams::default()
    };
    let got = extract(img.view(), &params).expect("extract");
    assert_eq!(
        got.points.len(),
        120,
        "two stripes of 60 rows, specks dropped"
    );
    assert!(got.points.iter().all(|p| p.x < 40.0 || p.x > 70.0));
}
