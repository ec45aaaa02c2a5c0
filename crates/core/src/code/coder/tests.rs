//! The per-frame coder against the physics of flat plates, raised plates, edges, fragments and ghosts, and its
//! pruned passes against the full ones.

use super::*;
use crate::code::test_point as point;
use crate::sensor::Sensor;

/// Points of a flat surface at height `z` for all stripes whose column is in view, rows `rows`.
fn flat(
    model: &FullModel,
    sensor: &Sensor,
    z: f64,
    rows: std::ops::Range<u32>,
) -> Vec<(StripePoint, u16)> {
    let mut out = Vec::new();
    for row in rows {
        for k in 0..sensor.laser.stripes {
            let u = model
                .column_at_height(k, f64::from(row), z)
                .expect("column");
            if u >= 0.0 && u <= f64::from(sensor.camera.width) - 1.0 {
                out.push((point(row, u), k as u16));
            }
        }
    }
    out
}

fn code(coder: &mut StripeCoder, pts: &[(StripePoint, u16)]) -> (Coding, usize) {
    let points: Vec<StripePoint> = pts.iter().map(|p| p.0).collect();
    let mut out = Coding::default();
    coder.code_into(&points, &mut out);
    let wrong = out
        .stripes
        .iter()
        .zip(pts)
        .filter(|(l, p)| l.is_some_and(|l| l != p.1))
        .count();
    (out, wrong)
}

#[test]
fn the_fuzzy_tables_follow_the_rules() {
    let t = FuzzyTables::shipped().expect("tables");
    assert!(t.same_segment(5.0, 0.05));
    assert!(!t.same_segment(5.0, 5.0));
    assert!(
        !t.same_segment(0.0, 0.0),
        "rule 1: belt points are not segments"
    );
    assert!(t.bridge_gap(1, 3.0), "rule 2: a very small gap is bridged");
    assert!(t.bridge_gap(50, 0.1), "rule 3");
    assert!(!t.bridge_gap(20, 3.0));
    assert!(!t.keep_segment(2), "rule 5");
    assert!(t.keep_segment(30));
}

#[test]
fn bands_contain_the_flat_surfaces_of_the_range() {
    let sensor = Sensor::default();
    let model = FullModel::nominal(&sensor);
    let coder = StripeCoder::new(&model, 648, 480, CodingParams::default()).expect("coder");
    for (p, k) in flat(&model, &sensor, 12.0, 0..480) {
        let (lo, hi) = coder.band(p.row, usize::from(k)).expect("band");
        assert!(p.x >= lo && p.x <= hi, "{p:?} stripe {k} band {lo}..{hi}");
    }
    assert!(coder.band(480, 0).is_none());
}

#[test]
fn a_flat_plate_at_any_height_is_coded_without_a_wrong_index() {
    let sensor = Sensor::default();
    let model = FullModel::nominal(&sensor);
    let mut coder = StripeCoder::new(&model, 648, 480, CodingParams::default()).expect("coder");
    for z in [0.0, 3.0, 7.5, 15.0, 30.0] {
        let pts = flat(&model, &sensor, z, 0..480);
        let (out, wrong) = code(&mut coder, &pts);
        assert_eq!(wrong, 0, "z = {z}");
        assert!(
            out.stats.coded as f64 > 0.99 * pts.len() as f64,
            "z = {z}: {:?}",
            out.stats
        );
    }
}

#[test]
fn a_raised_plate_with_a_hidden_stripe_is_coded_by_the_occlusion_rule() {
    // Rows 0..100 see the belt; rows 100..480 a plate 10 mm high whose left edge hides one stripe.
    let sensor = Sensor::default();
    let model = FullModel::nominal(&sensor);
    let mut coder = StripeCoder::new(&model, 648, 480, CodingParams::default()).expect("coder");
    let mut pts = flat(&model, &sensor, 0.0, 0..100);
    for (p, k) in flat(&model, &sensor, 0.0, 100..480) {
        if k == 0 || k == 10 {
            pts.push((p, k));
        }
    }
    for (p, k) in flat(&model, &sensor, 10.0, 100..480) {
        if (2..=9).contains(&k) {
            pts.push((p, k));
        }
    }
    pts.sort_by(|a, b| a.0.row.cmp(&b.0.row).then(a.0.x.total_cmp(&b.0.x)));
    let (out, wrong) = code(&mut coder, &pts);
    assert_eq!(wrong, 0);
    assert!(
        out.stats.coded as f64 > 0.99 * pts.len() as f64,
        "{:?}",
        out.stats
    );
}

#[test]
fn one_sheet_seen_on_both_sides_of_an_edge_is_one_stripe_twice() {
    // A plate 5 mm high under stripes 2-5 whose right edge runs along the rows between where sheet 5 meets its
    // top and where it meets the belt: sheet 5 lights both, so every row holds stripe 5 twice, then 6-10 on
    // the belt (stripes 0 and 1 on the belt left of the plate). Read one stripe over, the plate would lie below
    // the belt: the only readings are the right one and the one that calls the second point false.
    let sensor = Sensor::default();
    let model = FullModel::nominal(&sensor);
    let mut pts = Vec::new();
    for (p, k) in flat(&model, &sensor, 0.0, 100..480) {
        if k <= 1 || k >= 5 {
            pts.push((p, k));
        }
    }
    for (p, k) in flat(&model, &sensor, 5.0, 100..480) {
        if (2..=5).contains(&k) {
            pts.push((p, k));
        }
    }
    pts.sort_by(|a, b| a.0.row.cmp(&b.0.row).then(a.0.x.total_cmp(&b.0.x)));
    let mut coder = StripeCoder::new(&model, 648, 480, CodingParams::default()).expect("coder");
    let (out, wrong) = code(&mut coder, &pts);
    assert_eq!(wrong, 0, "{:?}", out.stats);
    let fives = pts
        .iter()
        .zip(&out.stripes)
        .filter(|((_, k), l)| *k == 5 && **l == Some(5))
        .count();
    assert_eq!(fives, 2 * 380, "both points of sheet 5 coded in every row");
    assert_eq!(out.stats.coded, pts.len(), "{:?}", out.stats);
    // A stray point halfway between two stripes of a flat belt is not a split: it stays false.
    let mut stray = flat(&model, &sensor, 0.0, 100..480);
    let extra: Vec<(StripePoint, u16)> = stray
        .windows(2)
        .filter(|w| w[0].0.row == w[1].0.row && w[0].1 == 4)
        .map(|w| (point(w[0].0.row, 0.5 * (w[0].0.x + w[1].0.x)), NO_LABEL))
        .collect();
    stray.extend(extra);
    stray.sort_by(|a, b| a.0.row.cmp(&b.0.row).then(a.0.x.total_cmp(&b.0.x)));
    let (out, wrong) = code(&mut coder, &stray);
    assert_eq!(wrong, 0, "{:?}", out.stats);
    for ((p, k), l) in stray.iter().zip(&out.stripes) {
        if *k == NO_LABEL {
            assert_eq!(*l, None, "the stray point stays false: {p:?}");
        }
    }
}

/// The demo's far edge: a plate 10 mm high (stripes 2-9) whose last stripe's sheet passes over the edge to the
/// belt; its tail lights the corner (a dim fragment halfway between stripes 9 and 10). Stripe 5 runs along a
/// hole's side in rows 250-270, cut there but as bright as ever.
fn far_edge(sensor: &Sensor, model: &FullModel, mark: bool) -> Vec<(StripePoint, u16)> {
    let mut pts = Vec::new();
    for (p, k) in flat(model, sensor, 0.0, 100..480) {
        if k == 0 || k == 10 {
            pts.push((p, k));
        }
    }
    for (p, k) in flat(model, sensor, 10.0, 100..480) {
        if (2..=9).contains(&k) {
            let cut = mark && k == 5 && (250..270).contains(&p.row);
            pts.push((StripePoint { cut, ..p }, k));
        }
        if k == 9 {
            let belt = model
                .column_at_height(10, f64::from(p.row), 0.0)
                .expect("column");
            let x = p.x + 0.5 * (belt - p.x);
            let intensity = 40.0;
            pts.push((
                StripePoint {
                    x,
                    intensity,
                    cut: mark,
                    ..p
                },
                NO_LABEL,
            ));
        }
    }
    pts.sort_by(|a, b| a.0.row.cmp(&b.0.row).then(a.0.x.total_cmp(&b.0.x)));
    pts
}

/// Rows 100..300 of the demo part's step, as the simulator shows them: stripes 2-4 on a level step 14 mm high,
/// 5-7 on the plate at 10 mm, 8 hidden by a boss whose top (18 mm) holds 9, and 10 on the belt beyond; all as
/// bright as each other. Read one stripe over, the step and the plate come out tilted.
fn step_rows(sensor: &Sensor, model: &FullModel) -> Vec<(StripePoint, u16)> {
    let mut pts = Vec::new();
    for (z, stripes) in [(14.0, 2..=4), (10.0, 5..=7), (18.0, 9..=9), (0.0, 10..=10)] {
        for (p, k) in flat(model, sensor, z, 100..300) {
            if stripes.contains(&k) {
                pts.push((p, k));
            }
        }
    }
    pts.sort_by(|a, b| a.0.row.cmp(&b.0.row).then(a.0.x.total_cmp(&b.0.x)));
    pts
}

#[test]
fn a_level_surface_is_read_level_rather_than_tilted_one_stripe_over() {
    let sensor = Sensor::default();
    let model = FullModel::nominal(&sensor);
    let pts = step_rows(&sensor, &model);
    let mut coder = StripeCoder::new(&model, 648, 480, CodingParams::default()).expect("coder");
    let (out, wrong) = code(&mut coder, &pts);
    assert_eq!(wrong, 0, "{:?}", out.stats);
    assert_eq!(out.stats.coded, pts.len(), "{:?}", out.stats);
    let level_blind = CodingParams {
        tilt_cost_per_mm: 0.0,
        ..CodingParams::default()
    };
    let mut coder = StripeCoder::new(&model, 648, 480, level_blind).expect("coder");
    let (out, wrong) = code(&mut coder, &pts);
    let right = out.stats.coded - wrong;
    assert!(
        right < pts.len() / 2,
        "without the tilt cost the step and the plate are not read right: {right} of {}",
        pts.len()
    );
}

#[test]
fn a_bright_top_does_not_continue_the_dim_belt_beside_it() {
    // A 30 mm block: its top's first stripe (7) lies on the column of the belt's next stripe (3) to within a
    // tenth of a pixel, and the block hides stripes 3-6. Read as belt stripe 3, the row costs what the truth
    // costs; the top is three times as bright as the belt. The belt's brightness condition is a tie-breaker
    // (below the margin): the rows' best reading of stripe 7 becomes the truth, which segments and tracks then
    // settle (on the simulated block, `crates/sim/tests/coding.rs`).
    let sensor = Sensor::default();
    let model = FullModel::nominal(&sensor);
    let mut pts = Vec::new();
    for (z, stripes, intensity) in [(0.0, 0..=2, 50.0), (30.0, 7..=10, 140.0)] {
        for (p, k) in flat(&model, &sensor, z, 100..400) {
            if stripes.contains(&k) {
                pts.push((StripePoint { intensity, ..p }, k));
            }
        }
    }
    pts.sort_by(|a, b| a.0.row.cmp(&b.0.row).then(a.0.x.total_cmp(&b.0.x)));
    // Rows whose best reading of stripe 7 is stripe 7.
    let read_right = |params: CodingParams| {
        let mut coder = StripeCoder::new(&model, 648, 480, params).expect("coder");
        let (out, wrong) = code(&mut coder, &pts);
        assert_eq!(wrong, 0, "{:?}", out.stats);
        pts.iter()
            .zip(&out.near)
            .filter(|((_, k), near)| *k == 7 && near[0] == 7)
            .count()
    };
    assert_eq!(read_right(CodingParams::default()), 300);
    let blind = CodingParams {
        belt_intensity_ratio: 0.0,
        ..CodingParams::default()
    };
    assert!(read_right(blind) < 300);
}

#[test]
fn cut_fragments_neither_shift_a_row_nor_go_unlabelled_on_a_stripe() {
    let sensor = Sensor::default();
    let model = FullModel::nominal(&sensor);
    // Without the marking it is the tilt cost of the row transitions that keeps the fragment from shifting the
    // rows (read one over, the plate comes out tilted); with neither, it shifts them.
    let neither = CodingParams {
        tilt_cost_per_mm: 0.0,
        ..CodingParams::default()
    };
    let mut coder = StripeCoder::new(&model, 648, 480, neither).expect("coder");
    let pts = far_edge(&sensor, &model, false);
    let (_, wrong_unmarked) = code(&mut coder, &pts);
    let mut coder = StripeCoder::new(&model, 648, 480, CodingParams::default()).expect("coder");
    let (_, wrong_unmarked_bright) = code(&mut coder, &pts);
    assert_eq!(wrong_unmarked_bright, 0);
    let pts = far_edge(&sensor, &model, true);
    let (out, wrong) = code(&mut coder, &pts);
    assert!(
        wrong_unmarked > 1000,
        "the fragment shifts the rows when not marked: {wrong_unmarked}"
    );
    assert_eq!(wrong, 0, "{:?}", out.stats);
    for ((p, k), l) in pts.iter().zip(&out.stripes) {
        if *k == NO_LABEL {
            assert_eq!(*l, None, "the corner fragment stays uncoded: {p:?}");
        }
        if *k == 5 && p.cut {
            assert_eq!(
                *l,
                Some(5),
                "the hole-side points follow their stripe: {p:?}"
            );
        }
    }
}

#[test]
fn faint_points_are_fragments_even_when_not_marked_cut() {
    // The corner fragment at a tenth of the stripes' peak and not marked cut (its cut too shallow to see): with
    // the faint rule it takes no part in reading the rows; without it, it shifts them.
    let sensor = Sensor::default();
    let model = FullModel::nominal(&sensor);
    let pts: Vec<(StripePoint, u16)> = far_edge(&sensor, &model, false)
        .into_iter()
        .map(|(p, k)| {
            let intensity = if k == NO_LABEL { 10.0 } else { p.intensity };
            (StripePoint { intensity, ..p }, k)
        })
        .collect();
    let mut coder = StripeCoder::new(&model, 648, 480, CodingParams::default()).expect("coder");
    let (out, wrong) = code(&mut coder, &pts);
    assert_eq!(wrong, 0, "{:?}", out.stats);
    for ((p, k), l) in pts.iter().zip(&out.stripes) {
        if *k == NO_LABEL {
            assert_eq!(*l, None, "the faint fragment stays uncoded: {p:?}");
        }
    }
    // Without the faint rule (and without the row transitions' tilt cost, which would keep this fragment from
    // shifting the rows too).
    let off = CodingParams {
        faint_intensity: 0.0,
        tilt_cost_per_mm: 0.0,
        ..CodingParams::default()
    };
    let mut coder = StripeCoder::new(&model, 648, 480, off).expect("coder");
    let (_, wrong_off) = code(&mut coder, &pts);
    assert!(
        wrong_off > 1000,
        "the faint point shifts the rows without the rule: {wrong_off}"
    );
}

/// The transition cost as [`CodingParams`] defines it, in `f64` comparisons.
#[allow(clippy::too_many_arguments)]
fn defined_cost(
    p: &CodingParams,
    from: u16,
    to: u16,
    za: f32,
    zb: f32,
    leftward: bool,
    ia: f32,
    ib: f32,
) -> f32 {
    let n = u32::from(to) - u32::from(from) - 1;
    if n == 0 {
        let d = zb - za;
        if f64::from(d.abs()) > p.jump_mm {
            return p.jump_cost as f32;
        }
        // The tilt (and the belt's cost) in single precision, as the rows are read.
        let tilt = (p.tilt_cost_per_mm as f32 * d.abs()).min(p.jump_cost as f32);
        let belt = f64::from(za.abs()) < p.rise_mm && f64::from(zb.abs()) < p.rise_mm;
        let (dim, bright) = (f64::from(ia.min(ib)), f64::from(ia.max(ib)));
        return if belt && dim < p.belt_intensity_ratio * bright {
            (tilt + p.belt_unlike_cost as f32).min(p.jump_cost as f32)
        } else {
            tilt
        };
    }
    let rise = if leftward { zb - za } else { za - zb };
    if f64::from(rise) >= p.rise_mm {
        (p.rise_skip_cost + f64::from(n) * p.edge_skip_cost) as f32
    } else {
        n as f32 * p.skip_cost as f32
    }
}

#[test]
fn tabulated_transition_costs_are_the_defined_ones_up_to_the_thresholds() {
    assert_eq!(next_f32(1.0, true), 1.0 + f32::EPSILON);
    assert_eq!(next_f32(1.0, false), 1.0 - f32::EPSILON / 2.0);
    assert_eq!(next_f32(-1.0, true), -1.0 + f32::EPSILON / 2.0);
    assert!(next_f32(0.0, false) < 0.0 && next_f32(0.0, true) > 0.0);
    assert_eq!(next_f32(f32::MAX, true), f32::INFINITY);
    let mut rng = crate::test_rng(0x7ab1e);
    // Thresholds that are not f32 numbers, so that rounding them the wrong way shows.
    for params in [
        CodingParams::default(),
        CodingParams {
            jump_mm: 0.3,
            rise_mm: 0.7,
            rise_skip_cost: 0.33,
            edge_skip_cost: 0.013,
            skip_cost: 1.1,
            tilt_cost_per_mm: 0.7,
            belt_intensity_ratio: 0.3,
            belt_unlike_cost: 0.2,
            ..CodingParams::default()
        },
    ] {
        let tr = Transitions::new(&params);
        for _ in 0..20_000 {
            let from = (rng() % 10) as u16;
            let to = from + 1 + (rng() % 4) as u16;
            // Heights anywhere, or on the belt (within a rise of it, and at that bound).
            let za = match rng() % 4 {
                0 => (rng() % 200) as f32 * 0.01 - 1.0,
                1 => next_f32(params.rise_mm as f32, rng() % 2 == 0),
                _ => (rng() % 4000) as f32 * 0.01,
            };
            // Differences right at, just below and just above either threshold, and anywhere.
            let at = [params.jump_mm as f32, params.rise_mm as f32][(rng() % 2) as usize];
            let d = match rng() % 4 {
                0 => at,
                1 => next_f32(at, true),
                2 => next_f32(at, false),
                _ => (rng() % 400) as f32 * 0.01 - 2.0,
            };
            let d = if rng() % 2 == 0 { d } else { -d };
            // zb chosen so that zb - za is d wherever f32 allows it.
            let zb = za + d;
            let leftward = rng() % 3 != 0;
            let sign = if leftward { 1.0 } else { -1.0 };
            // Peaks: alike, at the ratio, just either side of it, or anything.
            let ia = (1 + rng() % 4000) as f32;
            let at = (f64::from(ia) * params.belt_intensity_ratio) as f32;
            let ib = match rng() % 4 {
                0 => ia,
                1 => at,
                2 => next_f32(at, rng() % 2 == 0),
                _ => (rng() % 4000) as f32,
            };
            let (ia, ib) = if rng() % 2 == 0 { (ia, ib) } else { (ib, ia) };
            assert_eq!(
                tr.cost(from, to, za, zb, sign, ia, ib),
                defined_cost(&params, from, to, za, zb, leftward, ia, ib),
                "{from}->{to} za {za} zb {zb} leftward {leftward} peaks {ia} {ib} ({params:?})"
            );
        }
    }
}

#[test]
fn quick_edge_costs_are_the_general_ones() {
    let sensor = Sensor::default();
    let model = FullModel::nominal(&sensor);
    let coder = StripeCoder::new(&model, 648, 480, CodingParams::default()).expect("coder");
    let e = &coder.edges;
    // The paper's set-up is ordered on every row, so the quick way is the one taken.
    assert!(e.ordered.iter().all(|&o| o));
    let mut rng = crate::test_rng(0xed9e);
    for row in (0..480).step_by(7) {
        let r = row as usize * coder.stripes;
        // Heights at and around every threshold of the row, and anywhere in the range.
        let mut zs: Vec<f32> = e.left_at[r..r + coder.stripes]
            .iter()
            .chain(&e.right_at[r..r + coder.stripes])
            .filter(|t| t.is_finite())
            .flat_map(|&t| [t, next_f32(t, true), next_f32(t, false)])
            .collect();
        zs.extend((0..40).map(|_| (rng() % 5000) as f32 * 0.01 - 5.0));
        zs.extend([0.5f32, next_f32(0.5f32, false), f32::NAN]);
        for &z in &zs {
            for label in 0..coder.stripes as u16 {
                let general = (
                    coder.left_skip(row, label, z),
                    coder.right_skip(row, label, z),
                );
                let mut fresh = EdgeCursor::START;
                let quick = e.costs(&coder.transitions, row, label, z, &mut fresh);
                if z.is_nan() {
                    assert!(quick.is_none());
                    continue;
                }
                assert_eq!(quick, Some(general), "row {row} label {label} z {z}");
            }
        }
        // A cursor carried along growing heights, and back to a lower one, counts the same.
        zs.retain(|z| !z.is_nan());
        let mut cursor = EdgeCursor::START;
        for (i, &z) in zs.iter().enumerate() {
            let label = (i % coder.stripes) as u16;
            let general = (
                coder.left_skip(row, label, z),
                coder.right_skip(row, label, z),
            );
            let quick = e.costs(&coder.transitions, row, label, z, &mut cursor);
            assert_eq!(
                quick,
                Some(general),
                "row {row} label {label} z {z} (carried)"
            );
        }
    }
}

#[test]
fn the_pruned_row_passes_decide_what_the_full_passes_decide() {
    let sensor = Sensor::default();
    let model = FullModel::nominal(&sensor);
    let mut pruned = StripeCoder::new(&model, 648, 480, CodingParams::default()).expect("coder");
    let mut full = pruned.clone();
    full.window = f32::INFINITY;
    let mut narrow = pruned.clone();
    narrow.window = 0.05;
    let mut rng = crate::test_rng(0x9a55);
    let mut narrow_differs = false;
    for case in 0..12 {
        // Two surfaces (a step somewhere along the row), ghosts between stripes, points lost.
        let (z0, z1) = ((rng() % 300) as f64 * 0.1, (rng() % 300) as f64 * 0.1);
        let cut = 100.0 + (rng() % 400) as f64;
        let mut pts: Vec<StripePoint> = Vec::new();
        for row in (0..480).step_by(3) {
            for k in 0..sensor.laser.stripes {
                let at = |z| model.column_at_height(k, f64::from(row), z);
                let Some(u) = at(z0)
                    .filter(|&u| u < cut)
                    .or_else(|| at(z1).filter(|&u| u >= cut))
                else {
                    continue;
                };
                if (0.0..647.0).contains(&u) && rng() % 10 != 0 {
                    pts.push(point(row, u));
                }
            }
            for _ in 0..rng() % 3 {
                pts.push(point(row, (rng() % 640) as f64 + 0.5));
            }
        }
        pts.sort_by(|a, b| a.row.cmp(&b.row).then(a.x.total_cmp(&b.x)));
        let (mut a, mut b, mut c) = (Coding::default(), Coding::default(), Coding::default());
        pruned.code_into(&pts, &mut a);
        full.code_into(&pts, &mut b);
        narrow.code_into(&pts, &mut c);
        assert_eq!(a, b, "case {case}: z {z0} / {z1} from column {cut}");
        narrow_differs |= c != b;
    }
    // The comparison can tell: a window narrower than the decisions need changes them.
    assert!(narrow_differs);
}

#[test]
fn a_ghost_point_is_dropped_not_coded() {
    let sensor = Sensor::default();
    let model = FullModel::nominal(&sensor);
    let mut coder = StripeCoder::new(&model, 648, 480, CodingParams::default()).expect("coder");
    let mut pts = flat(&model, &sensor, 5.0, 0..480);
    // A short ghost segment between two stripes.
    let ghost: Vec<(StripePoint, u16)> = (200..203)
        .map(|r| {
            let a = pts
                .iter()
                .find(|p| p.0.row == r && p.1 == 4)
                .expect("p")
                .0
                .x;
            let b = pts
                .iter()
                .find(|p| p.0.row == r && p.1 == 5)
                .expect("p")
                .0
                .x;
            (point(r, 0.5 * (a + b)), NO_LABEL)
        })
        .collect();
    pts.extend(ghost);
    pts.sort_by(|a, b| a.0.row.cmp(&b.0.row).then(a.0.x.total_cmp(&b.0.x)));
    let (out, wrong) = code(&mut coder, &pts);
    assert_eq!(wrong, 0, "{:?}", out.stats);
    assert!(out.stats.noise + out.stats.ambiguous >= 3);
}

#[test]
fn points_outside_the_image_and_bad_parameters_are_handled() {
    let sensor = Sensor::default();
    let model = FullModel::nominal(&sensor);
    let mut coder = StripeCoder::new(&model, 648, 480, CodingParams::default()).expect("coder");
    let (out, _) = code(
        &mut coder,
        &[(point(900, 10.0), 0), (point(3, f64::NAN), 0)],
    );
    assert_eq!(out.stats.coded, 0);
    assert_eq!(out.stripes, vec![None, None]);
    let d = CodingParams::default;
    for bad in [
        CodingParams {
            max_height_mm: -5.0,
            ..d()
        },
        CodingParams {
            margin: f64::NAN,
            ..d()
        },
        // A negative cost would let the row passes stop before the best labelling; a huge run would overflow
        // them.
        CodingParams {
            outlier_cost: -0.1,
            ..d()
        },
        CodingParams {
            max_outlier_run: usize::MAX,
            ..d()
        },
    ] {
        assert!(
            StripeCoder::new(&model, 648, 480, bad.clone()).is_err(),
            "{bad:?}"
        );
    }
    let ratio = CodingParams {
        link_intensity_ratio: 1.5,
        ..CodingParams::default()
    };
    let err = StripeCoder::new(&model, 648, 480, ratio)
        .expect_err("a ratio above 1")
        .to_string();
    assert!(err.contains("link_intensity_ratio"), "{err}");
}
