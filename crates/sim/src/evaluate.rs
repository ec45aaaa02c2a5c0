//! Measuring stripe extraction against the simulator's exact ground truth, and the Cramér-Rao bound.
//!
//! A truth point is *found* when an extracted point lies on the same scan line within [`MATCH_RADIUS_PX`]; its
//! error is the signed difference of the nearest such point. An extracted point with no truth point within the
//! radius on its line is *false*.

use crate::render::TruthPoint;
use serde::Serialize;

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
        let mut by_row: std::collections::HashMap<u32, Vec<f64>> = std::collections::HashMap::new();
        for &(r, x) in extracted {
            by_row.entry(r).or_default().push(x);
        }
        let mut truth_by_row: std::collections::HashMap<u32, Vec<f64>> =
            std::collections::HashMap::new();
        for t in truth {
            truth_by_row.entry(t.row).or_default().push(t.u);
        }
        self.truth += truth.len();
        self.extracted += extracted.len();
        for t in truth {
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
