//! Reconciliation on synthetic tracks: interpolation, overrules by settled and segment-voted tracks, the row's
//! order, and what it never does (extrapolate, jump, guess).

use super::*;
use crate::code::test_point as point;

/// Frames of one row with stripes 0, 1, 2 at columns 100, 150, 200 (shifted by `drift` px per frame), every
/// point coded and row-confident.
fn frames(n: usize, drift: f64) -> Vec<CodedFrame> {
    (0..n)
        .map(|k| {
            let points: Vec<StripePoint> = [100.0, 150.0, 200.0]
                .iter()
                .map(|&x| StripePoint {
                    row: 7,
                    x: x + drift * k as f64,
                    intensity: 200.0,
                    width: 6.0,
                    score: 0.8,
                    cut: false,
                })
                .collect();
            CodedFrame {
                coding: Coding {
                    stripes: vec![Some(0), Some(1), Some(2)],
                    near: vec![
                        [0, NO_LABEL, NO_LABEL],
                        [1, NO_LABEL, NO_LABEL],
                        [2, NO_LABEL, NO_LABEL],
                    ],
                    row_confident: vec![true; 3],
                    stats: CodingStats {
                        points: 3,
                        coded: 3,
                        ..CodingStats::default()
                    },
                },
                points,
            }
        })
        .collect()
}

fn drop(f: &mut CodedFrame, i: usize, near: [u16; 3]) {
    f.coding.stripes[i] = None;
    f.coding.near[i] = near;
    f.coding.row_confident[i] = false;
    f.coding.stats.coded -= 1;
    f.coding.stats.ambiguous += 1;
}

proptest::proptest! {
    #[test]
    fn row_links_are_the_mutual_unique_nearest_pairs(
        mut xa in proptest::collection::vec(0.0f64..40.0, 0..12),
        mut xb in proptest::collection::vec(0.0f64..40.0, 0..12),
        link in 0.5f64..6.0,
    ) {
        // Coarse columns make ties and points exactly at the link distance common.
        for x in xa.iter_mut().chain(xb.iter_mut()) {
            *x = (*x * 4.0).round() / 4.0;
        }
        xa.sort_by(f64::total_cmp);
        xb.sort_by(f64::total_cmp);
        let pts = |xs: &[f64]| -> Vec<StripePoint> { xs.iter().map(|&x| point(0, x)).collect() };
        let (a, b) = (pts(&xa), pts(&xb));
        // The definition, by brute force: nearest both ways, within reach, no other point within reach.
        let nearest = |ps: &[StripePoint], x: f64| {
            ps.iter()
                .enumerate()
                .map(|(k, p)| (k, (p.x - x).abs()))
                .min_by(|u, v| u.1.total_cmp(&v.1))
        };
        let mut expected = Vec::new();
        for (i, p) in a.iter().enumerate() {
            let Some((j, d)) = nearest(&b, p.x) else { continue };
            let mutual = nearest(&a, b[j].x).is_some_and(|(ii, _)| ii == i);
            let others_a = a.iter().enumerate().any(|(ii, o)| ii != i && (o.x - b[j].x).abs() <= link);
            let others_b = b.iter().enumerate().any(|(jj, o)| jj != j && (o.x - p.x).abs() <= link);
            if d <= link && mutual && !others_a && !others_b {
                expected.push((i, j));
            }
        }
        proptest::prop_assert_eq!(row_links(&a, &b, link), expected);
    }
}

#[test]
fn a_dropped_point_between_agreeing_frames_takes_its_tracks_label() {
    let mut f = frames(9, 0.3);
    // The middle stripe is dropped in frames 3 and 4; its row could read it as 2 (cheapest) or 1.
    drop(&mut f[3], 1, [2, 1, NO_LABEL]);
    drop(&mut f[4], 1, [2, 1, NO_LABEL]);
    assert_eq!(reconcile(&mut f, &TemporalParams::default()), 2);
    assert_eq!(f[3].coding.stripes[1], Some(1));
    assert_eq!(f[4].coding.stats.coded, 3);
    assert_eq!(f[4].coding.stats.ambiguous, 0);
}

#[test]
fn a_frame_misread_with_confidence_among_frames_its_segments_coded_follows_them() {
    // 16 frames whose rows were all ambiguous and coded (right) by their segments, but for frame 6, whose row
    // read every stripe one over with confidence.
    let setup = |also_settled: Option<usize>| {
        let mut f = frames(16, 0.2);
        for (k, frame) in f.iter_mut().enumerate() {
            frame.coding.row_confident = vec![k == 6 || Some(k) == also_settled; 3];
            if k == 6 || Some(k) == also_settled {
                frame.coding.stripes = vec![Some(1), Some(2), Some(3)];
            }
        }
        f
    };
    let mut f = setup(None);
    assert_eq!(reconcile(&mut f, &TemporalParams::default()), 3);
    assert_eq!(f[6].coding.stripes, vec![Some(0), Some(1), Some(2)]);
    // Off: the confident reading stands.
    let mut f = setup(None);
    let off = TemporalParams {
        overrule_segment_votes: 0,
        ..TemporalParams::default()
    };
    assert_eq!(reconcile(&mut f, &off), 0);
    // A second frame whose row settled the same reading: the segments' labels no longer decide.
    let mut f = setup(Some(11));
    assert_eq!(reconcile(&mut f, &TemporalParams::default()), 0);
    assert_eq!(f[6].coding.stripes, vec![Some(1), Some(2), Some(3)]);
}

#[test]
fn segment_coded_and_settled_frames_together_overrule_a_tracks_last_frame() {
    // n frames whose rows were ambiguous and coded (right) by their segments, `settled` of them (the frames
    // before the last) settled right by their rows, and the last frame's row read every stripe one over with
    // confidence (a sheet about to vanish over an edge): no frame after it.
    let setup = |n: usize, settled: usize| {
        let mut f = frames(n, 0.2);
        let last = n - 1;
        for (k, frame) in f.iter_mut().enumerate() {
            frame.coding.row_confident = vec![k == last || k + 1 + settled > last; 3];
            if k == last {
                frame.coding.stripes = vec![Some(1), Some(2), Some(3)];
            }
        }
        f
    };
    // 12 segment-coded frames before it: overruled from the one side there is.
    let mut f = setup(13, 0);
    assert_eq!(reconcile(&mut f, &TemporalParams::default()), 3);
    assert_eq!(f[12].coding.stripes, vec![Some(0), Some(1), Some(2)]);
    // 9 segment-coded and 2 settled frames (9 + 2 x 2 = 13): overruled; 11 segment-coded alone are not enough.
    let mut f = setup(12, 2);
    assert_eq!(reconcile(&mut f, &TemporalParams::default()), 3);
    assert_eq!(f[11].coding.stripes, vec![Some(0), Some(1), Some(2)]);
    let mut f = setup(12, 0);
    assert_eq!(reconcile(&mut f, &TemporalParams::default()), 0);
    assert_eq!(f[11].coding.stripes, vec![Some(1), Some(2), Some(3)]);
}

#[test]
fn a_point_only_the_segment_vote_coded_at_its_tracks_end_follows_the_track() {
    // The last frame's middle stripe, sliding 1.5 px a frame, coded 0 by its segment (its row not settled):
    // its track's settled points before it read 1.
    let misread = |n: usize| {
        let mut f = frames(n, 1.5);
        let last = f.len() - 1;
        f[last].coding.stripes[1] = Some(0);
        f[last].coding.near[1] = [0, 1, NO_LABEL];
        f[last].coding.row_confident[1] = false;
        // Its left neighbour dropped, so that the row stays ordered either way.
        drop(&mut f[last], 0, [0, NO_LABEL, NO_LABEL]);
        f
    };
    let mut f = misread(7);
    assert_eq!(reconcile(&mut f, &TemporalParams::default()), 1);
    assert_eq!(f[6].coding.stripes[1], Some(1));
    // Fewer settled points than it takes to overrule a row (5 of 6): left alone.
    let mut f = misread(6);
    assert_eq!(reconcile(&mut f, &TemporalParams::default()), 0);
    assert_eq!(f[5].coding.stripes[1], Some(0));
    // A dropped point at the track's end is not extrapolated (the row's last, which its order does not pin
    // down either).
    let mut f = frames(7, 1.5);
    drop(&mut f[6], 2, [2, 1, NO_LABEL]);
    assert_eq!(reconcile(&mut f, &TemporalParams::default()), 0);
}

#[test]
fn a_row_only_the_segment_vote_coded_follows_its_tracks_as_a_whole() {
    let mut f = frames(12, 0.2);
    // Frame 4's row read one stripe over, its own labelling not settled (the segment vote coded it).
    for i in 0..3 {
        f[4].coding.stripes[i] = Some(i as u16 + 1);
        f[4].coding.near[i] = [i as u16 + 1, i as u16, NO_LABEL];
        f[4].coding.row_confident[i] = false;
    }
    // Frame 5 the same, but its first point was settled by its row: without overruling it keeps its label,
    // and relabelling the others alone would break the row's order, so none is changed.
    for i in 0..3 {
        f[5].coding.stripes[i] = Some(i as u16 + 1);
        f[5].coding.near[i] = [i as u16 + 1, i as u16, NO_LABEL];
        f[5].coding.row_confident[i] = i == 0;
    }
    let mut overruled = f.clone();
    let params = TemporalParams {
        overrule_votes: 0,
        ..TemporalParams::default()
    };
    assert_eq!(reconcile(&mut f, &params), 3);
    assert_eq!(f[4].coding.stripes, vec![Some(0), Some(1), Some(2)]);
    assert_eq!(f[4].coding.stats.coded, 3);
    assert_eq!(f[5].coding.stripes, vec![Some(1), Some(2), Some(3)]);
    // With overruling (the default), the settled point follows its track too, and the row with it.
    assert_eq!(reconcile(&mut overruled, &TemporalParams::default()), 6);
    assert_eq!(overruled[5].coding.stripes, vec![Some(0), Some(1), Some(2)]);
}

/// Frame `k` of [`frames`] misread with confidence: a ghost at column 175 read as stripe 2, so that the
/// stripe at 200 reads as 3.
fn misread(f: &mut CodedFrame) {
    f.points.insert(
        2,
        StripePoint {
            x: 175.0 + (f.points[2].x - 200.0),
            intensity: 40.0,
            ..f.points[2]
        },
    );
    f.coding.stripes = vec![Some(0), Some(1), Some(2), Some(3)];
    f.coding.near = vec![
        [0, NO_LABEL, NO_LABEL],
        [1, NO_LABEL, NO_LABEL],
        [2, NO_LABEL, NO_LABEL],
        [3, NO_LABEL, NO_LABEL],
    ];
    f.coding.row_confident = vec![true; 4];
    f.coding.stats.points = 4;
    f.coding.stats.coded = 4;
}

#[test]
fn tracks_overrule_a_frame_misread_with_confidence() {
    let mut f = frames(16, 0.2);
    misread(&mut f[6]);
    // Overruling off: a confident reading stands.
    let mut off = f.clone();
    let params = TemporalParams {
        overrule_votes: 0,
        ..TemporalParams::default()
    };
    assert_eq!(reconcile(&mut off, &params), 0);
    assert_eq!(off[6].coding.stripes[3], Some(3));
    // On: the stripe at 200 takes its track's label, and the ghost, which no track supports and which now
    // breaks the row's order, is dropped.
    assert_eq!(reconcile(&mut f, &TemporalParams::default()), 2);
    assert_eq!(f[6].coding.stripes, vec![Some(0), Some(1), None, Some(2)]);
    assert_eq!(f[6].coding.stats.coded, 3);
    assert_eq!(f[6].coding.stats.ambiguous, 1);
    // The same misreading in the scan's first frame: its track reaches it from the one side there is, with as
    // many settled points, and overrules it the same way.
    let mut g = frames(16, 0.2);
    misread(&mut g[0]);
    assert_eq!(reconcile(&mut g, &TemporalParams::default()), 2);
    assert_eq!(g[0].coding.stripes, vec![Some(0), Some(1), None, Some(2)]);
    // With fewer settled points after it than it takes (5 of 6), it stands.
    let mut g = frames(6, 0.2);
    misread(&mut g[0]);
    assert_eq!(reconcile(&mut g, &TemporalParams::default()), 0);
    assert_eq!(g[0].coding.stripes[3], Some(3));
    // Mid-scan, where the stripe's track ends (the sheet slid over an edge and vanished after frame 12): the
    // misreading of its last frame is overruled from the one side there is, as at the scan's ends.
    let mut h = frames(16, 0.2);
    for f in &mut h[13..] {
        f.points.truncate(2);
        f.coding.stripes.truncate(2);
        f.coding.near.truncate(2);
        f.coding.row_confident.truncate(2);
        f.coding.stats.points = 2;
        f.coding.stats.coded = 2;
    }
    misread(&mut h[12]);
    assert_eq!(reconcile(&mut h, &TemporalParams::default()), 2);
    assert_eq!(h[12].coding.stripes, vec![Some(0), Some(1), None, Some(2)]);
}

/// 16 frames of three stripes whose middle track's settled points read 1 in all but two frames (9 there: a
/// share of 0.86, too little for a track to decide alone).
fn frames_with_a_weak_middle_track() -> Vec<CodedFrame> {
    let mut f = frames(16, 0.2);
    for k in [2, 12] {
        f[k].coding.stripes[1] = Some(9);
    }
    f
}

#[test]
fn a_point_the_rows_order_leaves_one_label_takes_its_tracks_majority() {
    // Dropped between 0 and 2 in frame 6: its track's 13 of 15 votes for 1 do not reach the share, but the row
    // leaves it 1 alone.
    let mut f = frames_with_a_weak_middle_track();
    drop(&mut f[6], 1, [1, 0, 2]);
    assert_eq!(reconcile(&mut f, &TemporalParams::default()), 1);
    assert_eq!(f[6].coding.stripes[1], Some(1));
    // Not where its own row could not take that label.
    let mut g = frames_with_a_weak_middle_track();
    drop(&mut g[6], 1, [0, 2, NO_LABEL]);
    assert_eq!(reconcile(&mut g, &TemporalParams::default()), 0);
    // A track that never settled (every row of it ambiguous, or the scan's last frames): the row's order alone
    // gives the point its label, unless its track reads another label.
    let mut u = frames(6, 0.0);
    for fr in u.iter_mut() {
        fr.coding.row_confident[1] = false;
    }
    drop(&mut u[5], 1, [0, 1, 2]);
    assert_eq!(reconcile(&mut u, &TemporalParams::default()), 1);
    assert_eq!(u[5].coding.stripes[1], Some(1));
    let mut o = frames(6, 0.0);
    for fr in o.iter_mut().take(4) {
        fr.coding.stripes[1] = Some(7);
    }
    drop(&mut o[5], 1, [0, 1, 2]);
    reconcile(&mut o, &TemporalParams::default());
    assert_eq!(o[5].coding.stripes[1], None);
    // A frame misread with confidence from the middle stripe on (a ghost at 175 read as 3, the last stripe as
    // 4): the last stripe's track overrules it to 2, the ghost is dropped, and the middle stripe, which its
    // weak track cannot overrule, takes the one label left between 0 and 2 instead of being dropped.
    let mut h = frames_with_a_weak_middle_track();
    misread(&mut h[6]);
    h[6].coding.stripes = vec![Some(0), Some(2), Some(3), Some(4)];
    reconcile(&mut h, &TemporalParams::default());
    assert_eq!(h[6].coding.stripes, vec![Some(0), Some(1), None, Some(2)]);
}

#[test]
fn a_point_dropped_by_a_frame_read_one_over_takes_its_firm_tracks_label() {
    // Frame 6: a dim fragment right of the last stripe (a sheet's leading edge on a part's corner) is read
    // with confidence as stripe 2, and the stripe at 200 was dropped: its row would only read it as 1.
    let setup = |n: usize| {
        let mut f = frames(n, 0.2);
        let fr = &mut f[n / 2];
        fr.points.push(StripePoint {
            x: 225.0,
            intensity: 15.0,
            ..fr.points[2]
        });
        fr.coding.stripes.push(Some(2));
        fr.coding.near.push([2, NO_LABEL, NO_LABEL]);
        fr.coding.row_confident.push(true);
        fr.coding.stats.points += 1;
        drop(fr, 2, [1, NO_LABEL, NO_LABEL]);
        f
    };
    // Its track settled 2 in 8 frames before and 7 after: the point takes 2 though its row would not, and the
    // fragment, which no track supports and which now breaks the row's order, gives way.
    let mut f = setup(16);
    assert_eq!(reconcile(&mut f, &TemporalParams::default()), 2);
    assert_eq!(f[8].coding.stripes, vec![Some(0), Some(1), Some(2), None]);
    // With 5 settled frames around it (3 before, 2 after), fewer than overrule a row: the row's reading stands.
    let mut g = setup(6);
    assert_eq!(reconcile(&mut g, &TemporalParams::default()), 0);
    assert_eq!(g[3].coding.stripes[2], None);
    // Nor with overruling off.
    let mut h = setup(16);
    let off = TemporalParams {
        overrule_votes: 0,
        ..TemporalParams::default()
    };
    assert_eq!(reconcile(&mut h, &off), 0);
}

#[test]
fn two_supported_labels_in_conflict_overrule_nothing() {
    let mut f = frames(16, 0.2);
    // The ghost's column is lit in every frame and read as 2 there: its track supports it as much as the
    // stripe's track supports 2 at column 200 (the other frames' rows are not ordered, which the coder would
    // not give, but only their votes matter here).
    for fr in f.iter_mut() {
        misread(fr);
        fr.coding.stripes[3] = Some(2);
    }
    f[6].coding.stripes[3] = Some(3);
    let before = f[6].coding.stripes.clone();
    assert_eq!(reconcile(&mut f, &TemporalParams::default()), 0);
    assert_eq!(f[6].coding.stripes, before);
}

#[test]
fn reconciliation_never_extrapolates_jumps_or_guesses() {
    // Dropped in the last frame: no coded point after it (the row's last point, which the row's order does not
    // pin down either).
    let mut f = frames(6, 0.0);
    drop(&mut f[5], 2, [2, 1, NO_LABEL]);
    assert_eq!(reconcile(&mut f, &TemporalParams::default()), 0);
    // (The row's last point from here on: a point between two labelled neighbours that leave it one label can
    // take it by the row's order alone, which is not what these cases test.)
    // A jump of 5 px between frames ends the track.
    let mut f = frames(7, 5.0);
    drop(&mut f[3], 2, [2, 1, NO_LABEL]);
    assert_eq!(reconcile(&mut f, &TemporalParams::default()), 0);
    // The track's label is not one the row could take, and the track (5 settled points) is not firm enough to
    // overrule the row (`a_point_dropped_by_a_frame_read_one_over_takes_its_firm_tracks_label`).
    let mut f = frames(6, 0.0);
    drop(&mut f[3], 2, [1, NO_LABEL, NO_LABEL]);
    assert_eq!(reconcile(&mut f, &TemporalParams::default()), 0);
    // The label would break the row's order (its right neighbour was coded 1).
    let mut f = frames(7, 0.0);
    drop(&mut f[3], 1, [1, 2, NO_LABEL]);
    f[3].coding.stripes[2] = Some(1);
    assert_eq!(reconcile(&mut f, &TemporalParams::default()), 0);
    // Two candidates within the link distance: no link.
    let mut f = frames(7, 0.0);
    drop(&mut f[3], 2, [2, 1, NO_LABEL]);
    f[3].points[1].x = 199.5;
    assert_eq!(reconcile(&mut f, &TemporalParams::default()), 0);
    // Frames whose points and coding disagree in length are left alone.
    let mut f = frames(7, 0.0);
    drop(&mut f[3], 1, [1, 2, NO_LABEL]);
    f[2].coding.stripes.pop();
    assert_eq!(reconcile(&mut f, &TemporalParams::default()), 0);
}
