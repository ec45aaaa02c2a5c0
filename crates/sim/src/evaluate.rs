//! Measuring stripe extraction and stripe coding against the simulator's exact ground truth, and the Cramér-Rao
//! bound.
//!
//! A truth point is *found* when an extracted point lies on the same scan line within [`MATCH_RADIUS_PX`]; its
//! error is the signed difference of the nearest such point. An extracted point with no truth point within the
//! radius on its line is *false*. A coded point is checked against the stripe of the truth point of its scan line
//! nearest to it within the same radius ([`CodingScore`]).

use crate::render::TruthPoint;
use serde::Serialize;
use std::collections::BTreeMap;
use stripe3d_core::code::CodedFrame;
use stripe3d_core::extract::StripePoint;

/// Largest distance (pixels) at which an extracted point counts as finding a truth point.
pub const MATCH_RADIUS_PX: f64 = 0.5;

/// Accumulated comparison of extracted points with truth points.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Score {
    /// Truth points.
    pub truth: usize,
    /// Truth points found.
    pub found: usize,
    /// Extracted points.
    pub extracted: usize,
    /// Extracted points that match no truth point.
    pub false_points: usize,
    /// Sum of errors of found points.
    pub sum_error: f64,
    /// Sum of squared errors of found points.
    pub sum_sq_error: f64,
}

impl Score {
    /// Adds one frame: `truth` and the extracted `(line, x)` positions.
    pub fn add(&mut self, truth: &[TruthPoint], extracted: &[(u32, f64)]) {
        self.add_where(truth, extracted, |_, _| true);
    }

    /// [`Score::add`] counting only the truth points and extracted points at the `(line, x)` positions `keep`
    /// accepts, each still matched against all of the other side (a kept truth point found by any extracted point is
    /// found; a kept extracted point near any truth point is not false).
    pub fn add_where(
        &mut self,
        truth: &[TruthPoint],
        extracted: &[(u32, f64)],
        keep: impl Fn(u32, f64) -> bool,
    ) {
        let mut by_row: std::collections::HashMap<u32, Vec<f64>> = std::collections::HashMap::new();
        for &(r, x) in extracted {
            by_row.entry(r).or_default().push(x);
        }
        let mut truth_by_row: std::collections::HashMap<u32, Vec<f64>> =
            std::collections::HashMap::new();
        for t in truth {
            truth_by_row.entry(t.row).or_default().push(t.u);
        }
        for t in truth {
            if !keep(t.row, t.u) {
                continue;
            }
            self.truth += 1;
            let nearest = by_row.get(&t.row).and_then(|xs| {
                xs.iter()
                    .map(|x| x - t.u)
                    .min_by(|a, b| a.abs().total_cmp(&b.abs()))
            });
            if let Some(e) = nearest.filter(|e| e.abs() <= MATCH_RADIUS_PX) {
                self.found += 1;
                self.sum_error += e;
                self.sum_sq_error += e * e;
            }
        }
        for &(r, x) in extracted {
            if !keep(r, x) {
                continue;
            }
            self.extracted += 1;
            let matched = truth_by_row
                .get(&r)
                .is_some_and(|us| us.iter().any(|u| (x - u).abs() <= MATCH_RADIUS_PX));
            if !matched {
                self.false_points += 1;
            }
        }
    }

    /// Mean signed error of found points, pixels.
    pub fn bias(&self) -> f64 {
        self.sum_error / self.found.max(1) as f64
    }

    /// Root-mean-square error of found points, pixels.
    pub fn rms(&self) -> f64 {
        (self.sum_sq_error / self.found.max(1) as f64).sqrt()
    }

    /// Found truth points over all truth points.
    pub fn detection_rate(&self) -> f64 {
        self.found as f64 / self.truth.max(1) as f64
    }

    /// False points over all extracted points.
    pub fn false_rate(&self) -> f64 {
        self.false_points as f64 / self.extracted.max(1) as f64
    }
}

/// Distance (pixels) beyond which a reported point is false under the validation sets' rule: farther than this from
/// every true centre of its row (`../shared/validation/README.md`).
pub const VALIDATION_FALSE_PX: f64 = 1.5;

/// Extraction scored by the validation sets' rule: for each true centre, the nearest reported point of its row
/// within [`MATCH_RADIUS_PX`] finds it, each reported point used once (closest pairs first); a reported point
/// farther than [`VALIDATION_FALSE_PX`] from every true centre of its row is false.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct RowScore {
    /// True centres.
    pub truth: usize,
    /// True centres found.
    pub found: usize,
    /// Reported points.
    pub reported: usize,
    /// Reported points farther than [`VALIDATION_FALSE_PX`] from every true centre of their row.
    pub false_points: usize,
    /// Sum of the signed errors (reported − true) of the found centres, pixels.
    pub sum_error: f64,
    /// Sum of their squares.
    pub sum_sq_error: f64,
}

impl RowScore {
    /// Scores one frame: true centres and reported points as `(row, x)`, in any order.
    pub fn of(truth: &[(u32, f64)], reported: &[(u32, f64)]) -> Self {
        let mut t: Vec<(u32, f64)> = truth.to_vec();
        let mut r: Vec<(u32, f64)> = reported.to_vec();
        let by_row = |a: &(u32, f64), b: &(u32, f64)| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1));
        t.sort_by(by_row);
        r.sort_by(by_row);
        let mut s = RowScore {
            truth: t.len(),
            reported: r.len(),
            ..RowScore::default()
        };
        let (mut i, mut j) = (0, 0);
        let mut pairs: Vec<(f64, usize, usize)> = Vec::new();
        while i < t.len() || j < r.len() {
            let row = match (t.get(i), r.get(j)) {
                (Some(a), Some(b)) => a.0.min(b.0),
                (Some(a), None) => a.0,
                (None, Some(b)) => b.0,
                (None, None) => break,
            };
            let ti = i + t[i..].iter().take_while(|p| p.0 == row).count();
            let rj = j + r[j..].iter().take_while(|p| p.0 == row).count();
            let (tr, rr) = (&t[i..ti], &r[j..rj]);
            pairs.clear();
            for (a, tp) in tr.iter().enumerate() {
                for (b, rp) in rr.iter().enumerate() {
                    let d = (rp.1 - tp.1).abs();
                    if d <= MATCH_RADIUS_PX {
                        pairs.push((d, a, b));
                    }
                }
            }
            pairs.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)).then(x.2.cmp(&y.2)));
            let (mut t_used, mut r_used) = (vec![false; tr.len()], vec![false; rr.len()]);
            for &(_, a, b) in &pairs {
                if t_used[a] || r_used[b] {
                    continue;
                }
                t_used[a] = true;
                r_used[b] = true;
                let e = rr[b].1 - tr[a].1;
                s.found += 1;
                s.sum_error += e;
                s.sum_sq_error += e * e;
            }
            s.false_points += rr
                .iter()
                .filter(|rp| {
                    tr.iter()
                        .all(|tp| (rp.1 - tp.1).abs() > VALIDATION_FALSE_PX)
                })
                .count();
            (i, j) = (ti, rj);
        }
        s
    }

    /// Adds another frame's score.
    pub fn add(&mut self, o: &RowScore) {
        self.truth += o.truth;
        self.found += o.found;
        self.reported += o.reported;
        self.false_points += o.false_points;
        self.sum_error += o.sum_error;
        self.sum_sq_error += o.sum_sq_error;
    }

    /// Found over true centres.
    pub fn recall(&self) -> f64 {
        self.found as f64 / self.truth.max(1) as f64
    }

    /// False over reported points.
    pub fn false_rate(&self) -> f64 {
        self.false_points as f64 / self.reported.max(1) as f64
    }

    /// RMS error of the found centres, pixels.
    pub fn rms(&self) -> f64 {
        (self.sum_sq_error / self.found.max(1) as f64).sqrt()
    }
}

/// Cramér-Rao bound (pixels) on the position of a point-sampled Gaussian stripe of `amplitude` and `sigma`
/// (pixels) over `background`, whose centre lies `phase` pixels from the nearest pixel centre, with per-pixel noise
/// variance `variance(expected value)`: 1 / sqrt(Σ (∂f_i/∂c)² / var_i), the bound for an unbiased estimate of the
/// position when the stripe's shape is known.
pub fn cramer_rao_gaussian(
    amplitude: f64,
    sigma: f64,
    background: f64,
    phase: f64,
    variance: impl Fn(f64) -> f64,
) -> f64 {
    let mut info = 0.0;
    let reach = (6.0 * sigma).ceil() as i64 + 1;
    for i in -reach..=reach {
        let x = i as f64 - phase;
        let g = (-0.5 * (x / sigma).powi(2)).exp();
        let d = amplitude * x / (sigma * sigma) * g;
        info += d * d / variance(background + amplitude * g).max(1e-12);
    }
    if info > 0.0 {
        1.0 / info.sqrt()
    } else {
        f64::INFINITY
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn t(row: u32, u: f64) -> TruthPoint {
        TruthPoint {
            row,
            stripe: 0,
            u,
            world: [0.0; 3],
            part: [0.0; 3],
        }
    }

    #[test]
    fn scores_count_found_missed_and_false_points() {
        let mut s = Score::default();
        s.add(
            &[t(0, 10.0), t(0, 20.0), t(1, 10.0)],
            &[(0, 10.1), (0, 25.0), (1, 9.9)],
        );
        assert_eq!(
            (s.truth, s.found, s.extracted, s.false_points),
            (3, 2, 3, 1)
        );
        assert!(s.bias().abs() < 1e-12);
        assert!((s.rms() - 0.1).abs() < 1e-12);
        // Row 0 left out: only row 1's truth point and extracted point count.
        let mut s = Score::default();
        s.add_where(
            &[t(0, 10.0), t(0, 20.0), t(1, 10.0)],
            &[(0, 10.1), (0, 25.0), (1, 9.9)],
            |row, _| row == 1,
        );
        assert_eq!(
            (s.truth, s.found, s.extracted, s.false_points),
            (1, 1, 1, 0)
        );
        // Kept points are matched against all of the other side: the truth point at 20 is found by a point that
        // is not kept itself, and the kept point at 10.1 matches a truth point that is not kept.
        let mut s = Score::default();
        s.add_where(
            &[t(0, 10.0), t(0, 20.0)],
            &[(0, 10.1), (0, 19.8)],
            |_, x| x == 20.0 || x == 10.1,
        );
        assert_eq!(
            (s.truth, s.found, s.extracted, s.false_points),
            (1, 1, 1, 0)
        );
    }

    #[test]
    fn the_bound_matches_the_closed_form_for_a_gaussian_in_white_noise() {
        // (sigma_n / A) sqrt(2 sigma / sqrt(pi)) for a well-sampled Gaussian.
        let (a, s, n) = (200.0, 2.0, 2.0);
        let bound = cramer_rao_gaussian(a, s, 10.0, 0.3, |_| n * n);
        let closed = n / a * (2.0 * s / std::f64::consts::PI.sqrt()).sqrt();
        assert!(
            (bound - closed).abs() / closed < 0.01,
            "{bound} vs {closed}"
        );
    }
}

/// Stripe coding of one or more frames against the truth.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct CodingTally {
    /// Extracted points.
    pub points: usize,
    /// Of those, given a stripe index.
    pub coded: usize,
    /// Coded and matched to a truth point with that stripe.
    pub right: usize,
    /// Coded and matched to a truth point of another stripe.
    pub wrong: usize,
    /// Coded with no truth point within [`MATCH_RADIUS_PX`] (a sheet's tail, a ghost, a centre an edge pulls aside).
    pub off_truth: usize,
}

impl CodingTally {
    /// Share of the matched coded points that are right.
    pub fn right_share(&self) -> f64 {
        self.right as f64 / (self.right + self.wrong).max(1) as f64
    }

    /// Adds another tally.
    pub fn add(&mut self, b: &CodingTally) {
        self.points += b.points;
        self.coded += b.coded;
        self.right += b.right;
        self.wrong += b.wrong;
        self.off_truth += b.off_truth;
    }
}

/// One frame's truth points by image row: (column, stripe), for matching coded points.
#[derive(Debug, Clone, Default)]
pub struct TruthRows(Vec<Vec<(f64, u32)>>);

impl TruthRows {
    /// Indexes a frame's truth points by row.
    pub fn new(truth: &[TruthPoint]) -> Self {
        let rows = truth.iter().map(|t| t.row as usize + 1).max().unwrap_or(0);
        let mut by_row = vec![Vec::new(); rows];
        for t in truth {
            by_row[t.row as usize].push((t.u, t.stripe));
        }
        Self(by_row)
    }

    /// The stripe of the truth point of `p`'s row nearest to it within [`MATCH_RADIUS_PX`].
    pub fn stripe_of(&self, p: &StripePoint) -> Option<u32> {
        self.0
            .get(p.row as usize)?
            .iter()
            .map(|&(u, s)| ((u - p.x).abs(), s))
            .filter(|&(d, _)| d <= MATCH_RADIUS_PX)
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .map(|(_, s)| s)
    }
}

/// Where one kind of wrong index lies: points, first and last image row, leftmost and rightmost column.
pub type Spread = (usize, [u32; 2], [f64; 2]);

/// One coded frame against its truth.
#[derive(Debug, Default, Clone)]
pub struct CodingScore {
    /// The counts.
    pub tally: CodingTally,
    /// Wrong indices by (true stripe, label given).
    pub confusions: BTreeMap<(u32, u16), Spread>,
}

/// Scores one coded frame against its truth points.
pub fn score_coding(coded: &CodedFrame, truth: &TruthRows) -> CodingScore {
    let mut s = CodingScore::default();
    s.tally.points = coded.points.len();
    for (p, l) in coded.points.iter().zip(&coded.coding.stripes) {
        let Some(l) = *l else { continue };
        s.tally.coded += 1;
        match truth.stripe_of(p) {
            Some(t) if t == u32::from(l) => s.tally.right += 1,
            Some(t) => {
                s.tally.wrong += 1;
                let e = s
                    .confusions
                    .entry((t, l))
                    .or_insert((0, [p.row, p.row], [p.x, p.x]));
                e.0 += 1;
                e.1 = [e.1[0].min(p.row), e.1[1].max(p.row)];
                e.2 = [e.2[0].min(p.x), e.2[1].max(p.x)];
            }
            None => s.tally.off_truth += 1,
        }
    }
    s
}

#[cfg(test)]
mod row_score_tests {
    use super::*;

    #[test]
    fn each_reported_point_finds_one_true_centre_and_far_ones_are_false() {
        let truth = [(0, 10.0), (0, 10.8), (0, 30.0), (1, 5.0)];
        // 10.5 is within reach of both 10.0 and 10.8 but is used once (for 10.8, the closer); 31.0 is within 1.5 px of a
        // true centre (not false, not found); 40.0 and the point on row 2 (no truth) are false.
        let reported = [(0, 10.5), (0, 31.0), (0, 40.0), (1, 5.1), (2, 7.0)];
        let s = RowScore::of(&truth, &reported);
        assert_eq!((s.truth, s.found, s.reported, s.false_points), (4, 2, 5, 2));
        assert!(
            (s.rms() - ((0.09 + 0.01) / 2.0f64).sqrt()).abs() < 1e-9,
            "{}",
            s.rms()
        );
        assert!((s.recall() - 0.5).abs() < 1e-12 && (s.false_rate() - 0.4).abs() < 1e-12);
        let none = RowScore::of(&truth, &[]);
        assert_eq!((none.found, none.false_points, none.rms()), (0, 0, 0.0));
    }
}

#[cfg(test)]
mod coding_tests {
    use super::*;
    use stripe3d_core::code::Coding;

    fn point(row: u32, x: f64) -> StripePoint {
        StripePoint {
            row,
            x,
            intensity: 100.0,
            width: 6.0,
            score: 0.5,
            cut: false,
        }
    }

    #[test]
    fn coded_points_are_scored_against_the_nearest_truth_point_of_their_row() {
        let truth = TruthRows(vec![vec![(10.0, 0), (20.0, 1)], vec![(10.2, 0), (10.6, 1)]]);
        let coded = CodedFrame {
            points: vec![
                point(0, 10.3),
                point(0, 19.6),
                point(0, 30.0),
                point(1, 10.45),
                point(1, 10.0),
                point(5, 1.0),
            ],
            coding: Coding {
                stripes: vec![Some(0), Some(2), Some(3), Some(1), None, Some(0)],
                ..Coding::default()
            },
        };
        let s = score_coding(&coded, &truth);
        assert_eq!(
            s.tally,
            CodingTally {
                points: 6,
                coded: 5,
                right: 2,
                wrong: 1,
                off_truth: 2,
            }
        );
        assert_eq!(s.confusions.get(&(1, 2)), Some(&(1, [0, 0], [19.6, 19.6])));
        assert!((s.tally.right_share() - 2.0 / 3.0).abs() < 1e-12);
        let rows = TruthRows::new(&[TruthPoint {
            row: 3,
            stripe: 4,
            u: 7.0,
            world: [0.0; 3],
            part: [0.0; 3],
        }]);
        assert_eq!(rows.stripe_of(&point(3, 7.4)), Some(4));
        assert_eq!(rows.stripe_of(&point(3, 7.6)), None);
        assert_eq!(rows.stripe_of(&point(2, 7.0)), None);
    }
}
