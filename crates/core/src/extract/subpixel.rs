//! Sub-pixel stripe-centre estimators on one scan line (`../shared/reference/estimators.md`).
//!
//! Every estimator returns the centre with pixel centres at integer coordinates. Estimators that sum intensities
//! subtract the local background (the lower of the two bounding valleys). On a flat top (saturation) the
//! three-point estimators would see three equal values; they use the middle of the half-height crossings of the
//! plateau's flanks instead, which is unbiased for a symmetric stripe.

use super::peaks::Peak;
use crate::image::Pixel;

#[inline]
fn at<T: Pixel>(line: &[T], i: isize) -> f64 {
    let i = i.clamp(0, line.len() as isize - 1) as usize;
    f64::from(line[i].to_f32())
}

/// Local background under a peak: the lower of its two bounding valleys.
pub fn background<T: Pixel>(line: &[T], p: &Peak) -> f64 {
    at(line, p.roi_left as isize).min(at(line, p.roi_right as isize))
}

/// Centre of mass over `lo..=hi` of the intensities above `bg` (eq. 7-10 share this).
pub fn centre_of_mass<T: Pixel>(line: &[T], lo: usize, hi: usize, bg: f64) -> Option<f64> {
    let (mut s, mut sx) = (0.0, 0.0);
    let hi = hi.min(line.len().saturating_sub(1));
    for (i, p) in line.iter().enumerate().take(hi + 1).skip(lo) {
        let w = (f64::from(p.to_f32()) - bg).max(0.0);
        s += w;
        sx += w * i as f64;
    }
    (s > 0.0).then(|| sx / s)
}

/// Centre of mass of the pixels at least `level` above `bg`, in the contiguous run around the peak (eq. 10 on
/// one stripe).
pub fn centre_of_mass_threshold<T: Pixel>(
    line: &[T],
    p: &Peak,
    bg: f64,
    level: f64,
) -> Option<f64> {
    let above = |i: usize| f64::from(line[i].to_f32()) - bg >= level;
    let mut lo = p.top_start;
    while lo > p.roi_left && above(lo - 1) {
        lo -= 1;
    }
    let mut hi = p.top_end;
    while hi < p.roi_right && above(hi + 1) {
        hi += 1;
    }
    centre_of_mass(line, lo, hi, bg)
}

/// Sub-pixel positions where the profile crosses half height (between the background and the peak) on the left
/// and right flanks of the peak's top, by linear interpolation; a flank that stays above half height up to its
/// ROI bound crosses there.
pub fn half_height_crossings<T: Pixel>(line: &[T], p: &Peak, bg: f64) -> (f64, f64) {
    let level = 0.5 * (f64::from(p.value) + bg);
    let crossing = |from: usize, step: isize, stop: usize| -> f64 {
        let mut i = from as isize;
        loop {
            let next = i + step;
            if (step < 0 && next < stop as isize) || (step > 0 && next > stop as isize) {
                return i as f64;
            }
            let (vi, vn) = (at(line, i), at(line, next));
            if vn < level {
                return i as f64 + step as f64 * (vi - level) / (vi - vn);
            }
            i = next;
        }
    };
    (
        crossing(p.top_start, -1, p.roi_left),
        crossing(p.top_end, 1, p.roi_right),
    )
}

/// Middle of the two crossings of half height on the flanks of a flat top.
pub fn plateau_centre<T: Pixel>(line: &[T], p: &Peak, bg: f64) -> f64 {
    let (l, r) = half_height_crossings(line, p, bg);
    0.5 * (l + r)
}

/// Pixels on each side of a peak's top in which [`flank_asymmetry`] looks for the steepest step (stripes up to a
/// sigma of 5 px).
pub const FLANK_WINDOW: usize = 6;

/// Lopsidedness of the profile's flanks: |s_l − s_r| / (s_l + s_r), with s_l the steepest one-pixel rise from the
/// left bound of the region of interest to the top and s_r the steepest one-pixel fall from the top to the right
/// bound (0 for a symmetric stripe, 1 for a cliff on one side and no slope on the other). A stripe cut by an edge
/// (the tail of a sheet lighting a corner, half a stripe in an occluding edge's shadow) falls to the background
/// in one pixel on the cut side and slopes like a blurred stripe on the other. Unlike the distances from the centre
/// to the half-height crossings, this does not depend on the centre estimate, which sits between the crossings of a
/// cut profile as it does for a whole one.
///
/// Only the [`FLANK_WINDOW`] pixels next to the top are looked at: the steepest step of a Gaussian stripe lies one
/// sigma from its centre, and a cut lies at the top's edge; further out the region of interest may hold another
/// feature's slope (and the walk would cost as much as the estimate).
pub fn flank_asymmetry<T: Pixel>(line: &[T], p: &Peak) -> f64 {
    // Integer steps (pixels are integers; 16-bit differences fit an i32): exact, and a fifth of the cost of the
    // floating-point maxima, which marking pays on every point.
    let last = line.len().saturating_sub(1);
    let from = p.roi_left.max(p.top_start.saturating_sub(FLANK_WINDOW));
    let up = p.top_start.min(last);
    let mut rise = 0i32;
    if from < up {
        for w in line[from..=up].windows(2) {
            rise = rise.max(w[1].to_u32() as i32 - w[0].to_u32() as i32);
        }
    }
    let to = p.roi_right.min(p.top_end + FLANK_WINDOW).min(last);
    let mut fall = 0i32;
    if p.top_end < to {
        for w in line[p.top_end..=to].windows(2) {
            fall = fall.max(w[0].to_u32() as i32 - w[1].to_u32() as i32);
        }
    }
    if rise + fall > 0 {
        (f64::from(rise - fall) / f64::from(rise + fall)).abs()
    } else {
        0.0
    }
}

/// The three values around the peak, background subtracted: a = f(x-1), b = f(x), c = f(x+1).
fn three<T: Pixel>(line: &[T], x: usize, bg: f64) -> (f64, f64, f64) {
    let x = x as isize;
    (at(line, x - 1) - bg, at(line, x) - bg, at(line, x + 1) - bg)
}

/// Centre of mass of the peak and its two neighbours (eq. 8).
pub fn com3<T: Pixel>(line: &[T], p: &Peak, bg: f64) -> Option<f64> {
    if p.is_plateau() {
        return Some(plateau_centre(line, p, bg));
    }
    let x = p.top_start;
    centre_of_mass(line, x.saturating_sub(1), x + 1, bg)
}

/// Linear interpolation (eq. 11, corrected as in `estimators.md`).
pub fn linear<T: Pixel>(line: &[T], p: &Peak, bg: f64) -> Option<f64> {
    if p.is_plateau() {
        return Some(plateau_centre(line, p, bg));
    }
    let (a, b, c) = three(line, p.top_start, bg);
    let d = if c > a {
        0.5 * (c - a) / (b - a)
    } else {
        0.5 * (c - a) / (b - c)
    };
    d.is_finite().then_some(p.top_start as f64 + d)
}

/// Parabolic fit through three points (eq. 12).
pub fn parabolic<T: Pixel>(line: &[T], p: &Peak, bg: f64) -> Option<f64> {
    if p.is_plateau() {
        return Some(plateau_centre(line, p, bg));
    }
    let (a, b, c) = three(line, p.top_start, bg);
    let d = 0.5 * (a - c) / (a - 2.0 * b + c);
    d.is_finite().then_some(p.top_start as f64 + d)
}

/// Gaussian (parabola through the logarithms), values clamped at half a grey level above the background.
pub fn gaussian<T: Pixel>(line: &[T], p: &Peak, bg: f64) -> Option<f64> {
    if p.is_plateau() {
        return Some(plateau_centre(line, p, bg));
    }
    let (a, b, c) = three(line, p.top_start, bg);
    let floor = 0.5;
    let (la, lb, lc) = (a.max(floor).ln(), b.max(floor).ln(), c.max(floor).ln());
    let d = 0.5 * (la - lc) / (la - 2.0 * lb + lc);
    (d.is_finite() && d.abs() <= 1.0).then_some(p.top_start as f64 + d)
}

/// Blais-Rioux detector of order 4 (`half` = 2) or 8 (`half` = 4): zero crossing of
/// g(i) = sum_k f(i-k) - f(i+k), k = 1..half.
pub fn blais_rioux<T: Pixel>(line: &[T], p: &Peak, half: isize) -> Option<f64> {
    let g = |i: isize| -> f64 { (1..=half).map(|k| at(line, i - k) - at(line, i + k)).sum() };
    let x = p.center() as isize;
    let (a, c) = (at(line, x - 1), at(line, x + 1));
    let (g0, gl, gr) = (g(x), g(x - 1), g(x + 1));
    let est = if c > a {
        x as f64 + g0 / (g0 - gr)
    } else if c < a {
        (x - 1) as f64 + gl / (gl - g0)
    } else if g0 == 0.0 {
        x as f64
    } else if g0 < 0.0 {
        x as f64 + g0 / (g0 - gr)
    } else {
        (x - 1) as f64 + gl / (gl - g0)
    };
    (est.is_finite() && (est - x as f64).abs() <= 1.0).then_some(est)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A sampled Gaussian stripe of sigma `s` centred at `c` on a background of 10, quantised to u16 at high
    /// amplitude so quantisation is negligible.
    fn stripe(c: f64, s: f64) -> Vec<u16> {
        (0..64)
            .map(|i| (10.0 + 60000.0 * (-0.5 * ((i as f64 - c) / s).powi(2)).exp()).round() as u16)
            .collect()
    }

    fn peak(line: &[u16]) -> Peak {
        let mut out = Vec::new();
        super::super::peaks::dominant_peaks(line, 100, &mut out);
        assert_eq!(out.len(), 1);
        out[0]
    }

    #[test]
    fn the_gaussian_estimator_is_exact_on_gaussians_and_the_others_close() {
        for &c in &[30.0, 30.13, 30.37, 30.5, 30.81] {
            for &s in &[1.0, 2.0] {
                let line = stripe(c, s);
                let p = peak(&line);
                let bg = background(&line, &p);
                let g = gaussian(&line, &p, bg).expect("gaussian");
                assert!((g - c).abs() < 2e-3, "gaussian {g} vs {c}");
                let roi = centre_of_mass(&line, p.roi_left, p.roi_right, bg).expect("roi");
                assert!((roi - c).abs() < 0.01, "com-roi {roi} vs {c}");
                for (name, est, tol) in [
                    ("parabolic", parabolic(&line, &p, bg), 0.06),
                    ("linear", linear(&line, &p, bg), 0.09),
                    ("br4", blais_rioux(&line, &p, 2), 0.02),
                    ("br8", blais_rioux(&line, &p, 4), 0.02),
                    ("com3", com3(&line, &p, bg), 0.43),
                ] {
                    let e = est.unwrap_or_else(|| panic!("{name}"));
                    assert!((e - c).abs() < tol, "{name} {e} vs {c} (sigma {s})");
                }
            }
        }
    }

    #[test]
    fn saturated_plateaus_give_their_centre() {
        let mut line = stripe(30.3, 2.0);
        for x in line.iter_mut() {
            *x = (*x).min(40000);
        }
        let p = peak(&line);
        assert!(p.is_plateau());
        let bg = background(&line, &p);
        for est in [
            gaussian(&line, &p, bg),
            parabolic(&line, &p, bg),
            linear(&line, &p, bg),
            com3(&line, &p, bg),
        ] {
            let e = est.expect("estimate");
            assert!((e - 30.3).abs() < 0.05, "{e}");
        }
        let br = blais_rioux(&line, &p, 4).expect("br8");
        assert!((br - 30.3).abs() < 0.05, "{br}");
    }

    #[test]
    fn whole_stripes_are_symmetric_and_cut_ones_are_not() {
        for &s in &[1.0, 1.5, 2.0, 3.0] {
            for &c in &[30.0, 30.13, 30.37, 30.5, 30.81] {
                let whole = stripe(c, s);
                let a = flank_asymmetry(&whole, &peak(&whole));
                assert!(a < 0.3, "whole stripe sigma {s} at {c}: {a}");
                // The same stripe cut half a sigma right of its centre (an edge or the end of a sheet's tail).
                let mut cut = whole.clone();
                for (i, v) in cut.iter_mut().enumerate() {
                    if i as f64 > c + 0.5 * s {
                        *v = 10;
                    }
                }
                // A stripe of sigma 1 falls by up to 0.47 of its height in one pixel: cut at its top, it is no more
                // than 0.36 lopsided, below the default limit.
                let b = flank_asymmetry(&cut, &peak(&cut));
                assert!(s < 1.5 || b > 0.4, "cut stripe sigma {s} at {c}: {b}");
            }
        }
        // A saturated plateau falls as steeply on both sides.
        let mut sat = stripe(30.3, 2.0);
        for x in sat.iter_mut() {
            *x = (*x).min(40000);
        }
        let a = flank_asymmetry(&sat, &peak(&sat));
        assert!(a < 0.1, "{a}");
    }

    #[test]
    fn integer_flank_steps_equal_the_definition() {
        // The definition in floating point, step by step, against the integer implementation on random lines.
        let reference = |line: &[u16], p: &Peak| {
            let step = |i: usize| f64::from(line[i + 1]) - f64::from(line[i]);
            let last = line.len() - 1;
            let from = p.roi_left.max(p.top_start.saturating_sub(FLANK_WINDOW));
            let rise = (from..p.top_start.min(last)).map(step).fold(0.0, f64::max);
            let to = p.roi_right.min(p.top_end + FLANK_WINDOW).min(last);
            let fall = (p.top_end..to).map(|i| -step(i)).fold(0.0, f64::max);
            if rise + fall > 0.0 {
                ((rise - fall) / (rise + fall)).abs()
            } else {
                0.0
            }
        };
        let mut rng = 0x9e37_79b9u32;
        let mut peaks = Vec::new();
        let mut checked = 0;
        for _ in 0..300 {
            let line: Vec<u16> = (0..80)
                .map(|_| {
                    rng ^= rng << 13;
                    rng ^= rng >> 17;
                    rng ^= rng << 5;
                    // Mostly background with bright runs: stripes, cliffs and plateaus.
                    if rng % 7 < 2 {
                        (rng >> 8) as u16
                    } else {
                        (rng % 40) as u16
                    }
                })
                .collect();
            crate::extract::peaks::dominant_peaks(&line, 100, &mut peaks);
            for p in &peaks {
                assert_eq!(
                    flank_asymmetry(&line, p),
                    reference(&line, p),
                    "{line:?} {p:?}"
                );
                checked += 1;
            }
        }
        assert!(checked > 300, "{checked}");
    }
}
