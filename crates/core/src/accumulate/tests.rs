//! Profiles, range grids and their filling between frames against known surfaces.

use super::*;

fn prof(frame: usize, pts: &[(f64, f64, f64)]) -> Profile {
    Profile {
        frame,
        travel_mm: 0.0,
        points: pts
            .iter()
            .map(|&(x, y, z)| ProfilePoint {
                stripe: 0,
                row: 7,
                u: 0.0,
                x_mm: x,
                y_mm: y,
                z_mm: z,
                intensity: 1.0,
                spacetime: false,
            })
            .collect(),
    }
}

#[test]
fn index_conversions_are_the_plain_casts() {
    let mut rng = 3u64;
    for _ in 0..100_000 {
        rng = rng
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        let i = (rng >> 11) as usize >> (rng % 50);
        assert_eq!(index_f64(i).to_bits(), (i as f64).to_bits());
        let f = f64::from_bits(rng >> 2).abs();
        let f = if f.is_finite() && f < 9.0e18 {
            f
        } else {
            (rng % 1_000_000) as f64 / 7.0
        };
        assert_eq!(floor_index(f), f as usize, "{f}");
    }
    for f in [0.0, 0.5, 0.999_999_999, 1.0, 840.0, 840.999, 4.5e15] {
        assert_eq!(floor_index(f), f as usize);
    }
}

#[test]
fn intensities_are_registered_with_the_heights() {
    // Two samples 1 mm apart of one stripe and row, 100 and 50 grey levels, and a third across a step.
    let mut profiles = vec![
        prof(0, &[(0.0, 0.0, 1.0)]),
        prof(1, &[(1.0, 0.0, 1.0)]),
        prof(2, &[(2.0, 0.0, 5.0)]),
    ];
    for (p, i) in profiles.iter_mut().zip([100.0, 50.0, 80.0]) {
        p.points[0].intensity = i;
    }
    let params = RangeParams {
        spacing_mm: [0.25, 0.25],
        ..RangeParams::default()
    };
    let mut g = RangeGrid::covering(&profiles, params).expect("grid");
    g.accumulate(&profiles);
    let r = g.image();
    let intensity = r.intensity.as_deref().expect("intensities");
    assert_eq!(intensity.len(), r.z.len());
    let at = |x: f64| {
        let k = cell_index(r.origin_mm, r.spacing_mm, r.width, r.height, x, 0.0).expect("cell");
        intensity[k]
    };
    assert_eq!(at(0.0), 100.0);
    assert_eq!(at(1.0), 50.0);
    // Between the samples, the straight line between theirs; nothing across the step, as for the heights.
    assert!((at(0.5) - 75.0).abs() < 1e-4, "{}", at(0.5));
    assert!(at(1.5).is_nan());
    assert_eq!(at(2.0), 80.0);
    // Where there is no height there is no intensity, and the other way round.
    assert!(
        r.z.iter()
            .zip(intensity)
            .all(|(z, i)| z.is_finite() == i.is_finite())
    );
}

#[test]
fn samples_are_interpolated_along_travel_but_not_across_edges() {
    let profiles = vec![
        prof(0, &[(0.0, 0.0, 1.0)]),
        prof(1, &[(1.0, 0.0, 1.2)]),
        prof(2, &[(2.0, 0.0, 5.0)]),
    ];
    let params = RangeParams {
        spacing_mm: [0.25, 0.25],
        ..RangeParams::default()
    };
    let mut g = RangeGrid::covering(&profiles, params).expect("grid");
    g.accumulate(&profiles);
    let r = g.image();
    assert_eq!(r.at(0.0, 0.0), Some(1.0));
    assert!((r.at(0.5, 0.0).expect("filled") - 1.1).abs() < 1e-6);
    assert_eq!(r.at(1.5, 0.0), None, "a 3.8 mm step is not smeared");
    assert_eq!(r.at(2.0, 0.0), Some(5.0));
    assert_eq!(r.at(50.0, 0.0), None);
    assert_eq!(r.measured(), 1 + 3 + 1 + 1);
}

#[test]
fn a_bumps_top_between_samples_is_not_cut_by_a_chord() {
    // A cubic sampled every 0.5 mm (one sample a frame, part moving along −x under the stripe): the cells
    // between samples take the cubic's own heights (a chord would cut the top by up to 0.006 mm); the first
    // and last intervals, with a neighbour on one side only, the quadratic's.
    let f = |x: f64| 10.0 + 0.2 - 0.1 * x * x + 0.005 * x * x * x;
    let profiles: Vec<Profile> = (0..9)
        .map(|k| {
            let x = 2.0 - 0.5 * k as f64;
            prof(k, &[(x, 0.0, f(x))])
        })
        .collect();
    let params = RangeParams {
        spacing_mm: [0.125, 0.125],
        ..RangeParams::default()
    };
    let mut g = RangeGrid::covering(&profiles, params).expect("grid");
    g.accumulate(&profiles);
    let r = g.image();
    for c in 0..=24 {
        let x = -1.5 + 0.125 * c as f64;
        let z = f64::from(r.at(x, 0.0).expect("filled"));
        assert!((z - f(x)).abs() < 1e-5, "x {x}: {z} against {}", f(x));
    }
    let (x, quad) = (1.75, f64::from(r.at(1.75, 0.0).expect("filled")));
    assert!((quad - f(x)).abs() < 0.002 && (quad - f(x)).abs() > 1e-6);
}

#[test]
fn newtons_form_is_the_polynomial_through_the_nodes() {
    // Against Lagrange's form, written out, for one to four nodes at uneven spacing.
    let nodes = [(-1.0, 0.3), (0.0, 1.0), (0.5, -0.2), (1.75, 2.0)];
    for n in 1..=4 {
        let nodes = &nodes[..n];
        let lagrange = |t: f64| -> f64 {
            let mut z = 0.0;
            for (i, &(xi, zi)) in nodes.iter().enumerate() {
                let mut w = zi;
                for (j, &(xj, _)) in nodes.iter().enumerate() {
                    if j != i {
                        w *= (t - xj) / (xi - xj);
                    }
                }
                z += w;
            }
            z
        };
        let poly = Newton::through(nodes);
        for k in 0..=40 {
            let t = -1.5 + 0.09 * k as f64;
            assert!((poly.at(t) - lagrange(t)).abs() < 1e-9, "{n} nodes at {t}");
        }
    }
}

#[test]
fn a_close_or_steep_neighbour_leaves_the_chord() {
    let params = RangeParams {
        spacing_mm: [0.125, 0.125],
        max_fill_step_mm: 5.0,
        ..RangeParams::default()
    };
    let fill_at = |samples: &[(f64, f64)], x: f64| -> f64 {
        let profiles: Vec<Profile> = samples
            .iter()
            .enumerate()
            .map(|(k, &(x, z))| prof(k, &[(x, 0.0, z)]))
            .collect();
        let mut g = RangeGrid::covering(&profiles, params.clone()).expect("grid");
        g.accumulate(&profiles);
        f64::from(g.image().at(x, 0.0).expect("filled"))
    };
    // A neighbour 0.02 mm beyond an interval of 0.5 mm: the quadratic through it would dip 0.06 mm.
    let z = fill_at(&[(0.0, 1.0), (0.5, 1.0), (0.52, 1.01)], 0.25);
    assert!((z - 1.0).abs() < 1e-6, "{z}");
    // A neighbour 2 mm higher: the cubic would dip 0.125 mm below the chord, more than a smooth surface does.
    let z = fill_at(&[(0.0, 1.0), (0.5, 1.0), (1.0, 1.0), (1.5, 3.0)], 0.75);
    assert!((z - 1.0).abs() < 1e-6, "{z}");
    // A neighbour 0.2 mm higher bends it, as a smooth surface would.
    let z = fill_at(&[(0.0, 1.0), (0.5, 1.0), (1.0, 1.0), (1.5, 1.2)], 0.75);
    assert!((z - (1.0 - 0.0625 * 0.2)).abs() < 1e-6, "{z}");
}

#[test]
fn bands_filled_in_parallel_give_the_sums_of_one_pass() {
    // Three stripes on 80 image rows over 30 frames, each track wandering over several grid rows (a sheet's y
    // moves with the height under it): the grid filled by one thread and by four, in bands, is the same to the
    // bit, heights and intensities.
    let profiles: Vec<Profile> = (0..30)
        .map(|k| {
            let mut points = Vec::new();
            for stripe in 0..3u16 {
                for row in 0..80u32 {
                    let x = 10.0 * f64::from(stripe) - 0.5 * k as f64;
                    let z = 2.0 * (0.3 * k as f64 + 0.1 * f64::from(row)).sin();
                    points.push(ProfilePoint {
                        stripe,
                        row,
                        u: 0.0,
                        x_mm: x,
                        y_mm: -0.25 * f64::from(row) + 0.4 * z,
                        z_mm: z,
                        intensity: 50.0 + f32::from(stripe) + 0.5 * k as f32,
                        spacetime: false,
                    });
                }
            }
            Profile {
                frame: k,
                travel_mm: 0.5 * k as f64,
                points,
            }
        })
        .collect();
    let params = RangeParams {
        spacing_mm: [0.1, 0.1],
        max_fill_step_mm: 1.0,
        ..RangeParams::default()
    };
    let image_with = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool");
        pool.install(|| {
            let mut g = RangeGrid::covering(&profiles, params.clone()).expect("grid");
            assert!(
                g.height >= 4 * MIN_BAND_ROWS,
                "{} rows: too few for bands",
                g.height
            );
            g.accumulate(&profiles);
            g.image()
        })
    };
    let (one, four) = (image_with(1), image_with(4));
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert!(one.measured() > 10_000, "{} cells measured", one.measured());
    assert_eq!(bits(&one.z), bits(&four.z));
    assert_eq!(
        bits(one.intensity.as_deref().expect("intensity")),
        bits(four.intensity.as_deref().expect("intensity"))
    );
}

#[test]
fn an_update_of_a_few_points_redoes_only_their_part_of_a_track() {
    // One stripe, two rows, 40 frames; three points of row 8 move (at the track's start, in its middle, at its
    // end, one of them past the fill's step limit): their samples and the intervals they are nodes of are taken
    // back and added again, which must give what a fresh accumulation gives.
    let moved = [0usize, 20, 39];
    let scan = |bump: f64| -> Vec<Profile> {
        (0..40)
            .map(|k| {
                let x = 10.0 - 0.5 * k as f64;
                let mut p = prof(k, &[(x, 0.0, 1.0 + 0.01 * x * x)]);
                let mut q = p.points[0];
                q.row = 8;
                q.y_mm = -0.25;
                if moved.contains(&k) {
                    q.z_mm += if k == 20 { 0.5 * bump } else { 0.05 * bump };
                }
                p.points.push(q);
                p
            })
            .collect()
    };
    let params = RangeParams {
        spacing_mm: [0.125, 0.125],
        ..RangeParams::default()
    };
    let (before, after) = (scan(0.0), scan(1.0));
    let mut updated = RangeGrid::covering(&before, params.clone()).expect("grid");
    updated.accumulate_to_update(&before);
    let unchanged = updated.image();
    updated.update(&after, moved.iter().map(|&k| (k, 1)));
    let mut fresh = RangeGrid::covering(&after, params.clone()).expect("grid");
    fresh.accumulate(&after);
    let (u, f) = (updated.image(), fresh.image());
    let mut changed = 0;
    for ((a, b), c) in u.z.iter().zip(&f.z).zip(&unchanged.z) {
        assert_eq!(a.is_nan(), b.is_nan());
        if a.is_finite() {
            assert!((a - b).abs() < 1e-5, "{a} against {b}");
            changed += usize::from((a - c).abs() > 1e-4);
        }
    }
    for (a, b) in u
        .intensity
        .iter()
        .flatten()
        .zip(f.intensity.iter().flatten())
    {
        assert!(
            (a - b).abs() < 1e-3 || (a.is_nan() && b.is_nan()),
            "{a} against {b}"
        );
    }
    assert!(changed > 10, "{changed} cells changed");
    // And back: what the grid held before.
    updated.update(&before, moved.iter().map(|&k| (k, 1)));
    let u = updated.image();
    for (a, b) in u.z.iter().zip(&unchanged.z) {
        assert!(
            (a - b).abs() < 1e-5 || (a.is_nan() && b.is_nan()),
            "{a} against {b}"
        );
    }
}

#[test]
fn an_update_gives_what_a_fresh_accumulation_gives() {
    // Two rows of one stripe over 12 frames; the update moves heights on one row (one of them past the fill's
    // step limit, which unlinks it from its neighbours) and leaves the other alone, whose track is not redone.
    let scan = |bump: f64| -> Vec<Profile> {
        (0..12)
            .map(|k| {
                let x = 3.0 - 0.5 * k as f64;
                let mut p = prof(k, &[(x, 0.0, 1.0 + 0.1 * x * x)]);
                let mut q = p.points[0];
                q.row = 8;
                q.y_mm = -0.25;
                q.z_mm += if k == 5 { bump } else { 0.01 * bump * k as f64 };
                p.points.push(q);
                p
            })
            .collect()
    };
    let params = RangeParams {
        spacing_mm: [0.125, 0.125],
        ..RangeParams::default()
    };
    let (before, after) = (scan(0.0), scan(0.5));
    // The points that move: row 8's.
    let rows8 = (0..12).map(|k| (k, 1));
    let mut updated = RangeGrid::covering(&before, params.clone()).expect("grid");
    updated.accumulate_to_update(&before);
    let unchanged = updated.image();
    updated.update(&after, rows8.clone());
    let mut fresh = RangeGrid::covering(&after, params.clone()).expect("grid");
    fresh.accumulate(&after);
    let (u, f) = (updated.image(), fresh.image());
    assert_eq!(u.z.len(), f.z.len());
    let mut moved = 0;
    for ((a, b), c) in u.z.iter().zip(&f.z).zip(&unchanged.z) {
        assert_eq!(a.is_nan(), b.is_nan());
        if a.is_finite() {
            assert!((a - b).abs() < 1e-5, "{a} against {b}");
            moved += usize::from((a - c).abs() > 1e-3);
        }
    }
    assert!(moved > 20, "{moved} cells changed");
    // Other points (a frame less), or a grid that holds two scans: accumulated afresh.
    let fresh_of = |profiles: &[Profile]| {
        let mut g = RangeGrid::covering(&before, params.clone()).expect("grid");
        g.accumulate(profiles);
        g.image().z
    };
    let same = |a: &[f32], b: &[f32]| {
        a.len() == b.len()
            && a.iter()
                .zip(b)
                .all(|(a, b)| a == b || (a.is_nan() && b.is_nan()))
    };
    // Back again: the grid holds what the first update put in it.
    updated.update(&before, rows8.clone());
    let (u, b) = (updated.image().z, fresh_of(&before));
    assert!(
        u.iter()
            .zip(&b)
            .all(|(u, b)| (u - b).abs() < 1e-5 || (u.is_nan() && b.is_nan()))
    );
    // A point in another track (image row): accumulated afresh.
    let mut other = after.clone();
    other[3].points[1].row = 9;
    let mut g = RangeGrid::covering(&before, params.clone()).expect("grid");
    g.accumulate_to_update(&before);
    g.update(&other, rows8.clone());
    assert!(same(&g.image().z, &fresh_of(&other)));
    let fewer = &after[..11];
    let mut g = RangeGrid::covering(&before, params.clone()).expect("grid");
    g.accumulate_to_update(&before);
    g.update(fewer, rows8.clone());
    assert!(same(&g.image().z, &fresh_of(fewer)));
    let mut g = RangeGrid::covering(&before, params.clone()).expect("grid");
    g.accumulate_to_update(&before[..6]);
    g.accumulate_to_update(&before[6..]);
    g.update(&after, rows8.clone());
    assert!(same(&g.image().z, &fresh_of(&after)));
}

#[test]
fn empty_scans_and_bad_spacing_are_refused() {
    assert!(RangeGrid::covering(&[], RangeParams::default()).is_err());
    let p = vec![prof(0, &[(0.0, 0.0, 1.0)])];
    let bad = RangeParams {
        spacing_mm: [0.0, 0.1],
        ..RangeParams::default()
    };
    assert!(RangeGrid::covering(&p, bad).is_err());
    let huge = RangeParams {
        spacing_mm: [1e-6, 1e-6],
        ..RangeParams::default()
    };
    let p = vec![prof(0, &[(0.0, 0.0, 1.0), (100.0, 100.0, 1.0)])];
    assert!(RangeGrid::covering(&p, huge).is_err());
}
