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

/// How far a peak stands above its surroundings on *both* sides: its height over the higher of its two bounding
/// valleys (eq. 4's condition, a rise before and a fall after). The edge of a bright surface (a plate's side, a
/// printed cell) falls far on one side only, and is no peak by this measure however high the step.
pub fn prominence<T: Pixel>(line: &[T], p: &Peak) -> f64 {
    f64::from(p.value) - at(line, p.roi_left as isize).max(at(line, p.roi_right as isize))
}

/// Spans up to this many pixels take [`centre_of_mass`]'s integer path (its sums stay below 2^53, where the
/// floating-point sums are exact too, for 16-bit pixels on lines of up to 2^22 pixels).
const INTEGER_COM_MAX_SPAN: usize = 1 << 14;

/// Centre of mass over `lo..=hi` of the intensities above `bg` (eq. 7-10 share this).
pub fn centre_of_mass<T: Pixel>(line: &[T], lo: usize, hi: usize, bg: f64) -> Option<f64> {
    let hi = hi.min(line.len().saturating_sub(1));
    let bgi = bg as u32;
    if f64::from(bgi) == bg && hi.saturating_sub(lo) < INTEGER_COM_MAX_SPAN && line.len() <= 1 << 22
    {
        // The usual case, an integer background: the same sums in integers, exact (and so equal to the
        // floating-point sums, whose terms are integers too, below 2^53) and without a conversion per pixel.
        let (mut s, mut sx) = (0u64, 0u64);
        for (i, p) in line.iter().enumerate().take(hi + 1).skip(lo) {
            let w = u64::from(p.to_u32().saturating_sub(bgi));
            s += w;
            sx += w * i as u64;
        }
        return (s > 0).then(|| sx as f64 / s as f64);
    }
    let (mut s, mut sx) = (0.0, 0.0);
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
    let to = p.roi_right.min(p.top_end + FLANK_WINDOW).min(last);
    // Away from the line's ends: the FLANK_WINDOW steps on each side, those outside from..to masked to 0, over
    // fixed-size windows in a loop that compiles without branches or bounds checks (the windows' lengths vary from
    // point to point).
    let windows = p.top_start.checked_sub(FLANK_WINDOW).and_then(|up| {
        let left: &[T; FLANK_WINDOW + 1] = line.get(up..=p.top_start)?.try_into().ok()?;
        let down = p.top_end;
        let right: &[T; FLANK_WINDOW + 1] =
            line.get(down..=down + FLANK_WINDOW)?.try_into().ok()?;
        Some((up, left, down, right))
    });
    let (rise, fall) = if let Some((up, left, down, right)) = windows {
        let (mut rise, mut fall) = (0i32, 0i32);
        for j in 0..FLANK_WINDOW {
            let r = left[j + 1].to_u32() as i32 - left[j].to_u32() as i32;
            rise = rise.max(if up + j >= from { r } else { 0 });
            let f = right[j].to_u32() as i32 - right[j + 1].to_u32() as i32;
            fall = fall.max(if down + j < to { f } else { 0 });
        }
        (rise, fall)
    } else {
        let up = p.top_start.min(last);
        let mut rise = 0i32;
        if from < up {
            for w in line[from..=up].windows(2) {
                rise = rise.max(w[1].to_u32() as i32 - w[0].to_u32() as i32);
            }
        }
        let mut fall = 0i32;
        if p.top_end < to {
            for w in line[p.top_end..=to].windows(2) {
                fall = fall.max(w[0].to_u32() as i32 - w[1].to_u32() as i32);
            }
        }
        (rise, fall)
    };
    if rise + fall > 0 {
        (f64::from(rise - fall) / f64::from(rise + fall)).abs()
    } else {
        0.0
    }
}

/// The three values around the peak, background subtracted: a = f(x-1), b = f(x), c = f(x+1).
#[inline]
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
    // The lower neighbour sets the slope: b - a when c > a, else b - c (a minimum, not a branch, which the
    // stripe's sub-pixel phase would make unpredictable).
    let d = 0.5 * (c - a) / (b - a.min(c));
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

/// Levels up to this many grey levels above the background take their logarithm from a table.
const LN_TABLE_LEN: usize = 4096;

/// ln(max(v, 0.5)) for every integer level v below [`LN_TABLE_LEN`].
#[inline]
fn ln_table() -> &'static [f64; LN_TABLE_LEN] {
    static TABLE: std::sync::OnceLock<[f64; LN_TABLE_LEN]> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| std::array::from_fn(|i| (i as f64).max(0.5).ln()))
}

/// ln(max(v, 0.5)): the Gaussian estimator's logarithm of a level above the background, clamped at half a grey
/// level, from `table` ([`ln_table`]) for the integer levels it holds (three logarithms per point were a quarter of
/// a frame's extraction time; pixels and the background are integers, so the levels almost always are).
#[inline]
fn ln_level(table: &[f64], v: f64) -> f64 {
    let i = v as usize; // saturating: negative levels and NaN give 0
    if v <= 0.0 || (i < table.len() && i as f64 == v) {
        table[i.min(table.len() - 1)]
    } else {
        v.max(0.5).ln()
    }
}

/// Gaussian (parabola through the logarithms), values clamped at half a grey level above the background.
pub fn gaussian<T: Pixel>(line: &[T], p: &Peak, bg: f64) -> Option<f64> {
    if p.is_plateau() {
        return Some(plateau_centre(line, p, bg));
    }
    let table = ln_table();
    let x = p.top_start;
    let bgi = bg as i64;
    let (la, lb, lc) = match line.get(x.wrapping_sub(1)..=x + 1) {
        // The usual case, an integer background and the three pixels inside the line: integer levels, one check.
        Some(&[a, b, c]) if bgi as f64 == bg => {
            let ln = |p: T| {
                let v = i64::from(p.to_u32()) - bgi;
                match usize::try_from(v) {
                    Ok(i) if i < LN_TABLE_LEN => table[i],
                    Ok(_) => (v as f64).ln(),
                    Err(_) => table[0],
                }
            };
            (ln(a), ln(b), ln(c))
        }
        _ => {
            let (a, b, c) = three(line, x, bg);
            (ln_level(table, a), ln_level(table, b), ln_level(table, c))
        }
    };
    let d = 0.5 * (la - lc) / (la - 2.0 * lb + lc);
    (d.is_finite() && d.abs() <= 1.0).then_some(p.top_start as f64 + d)
}

/// Blais-Rioux detector of order 4 (`half` = 2) or 8 (`half` = 4): zero crossing of
/// g(i) = sum_k f(i-k) - f(i+k), k = 1..half.
pub fn blais_rioux<T: Pixel>(line: &[T], p: &Peak, half: isize) -> Option<f64> {
    let g = |i: isize| -> f64 { (1..=half).map(|k| at(line, i - k) - at(line, i + k)).sum() };
    let x = p.center() as isize;
    let (a, c) = (at(line, x - 1), at(line, x + 1));
    // Away from the line's ends the sums in integers (exact, as the floating-point sums of integers are).
    let window = usize::try_from(half).ok().and_then(|h| {
        let w = line.get(p.center().checked_sub(h + 1)?..=p.center() + h + 1)?;
        Some((h, w))
    });
    let (g0, gl, gr) = match window {
        Some((h, w)) => {
            // w[h + 1] is the centre pixel.
            let gi = |c: usize| -> f64 {
                let sum: i64 = (1..=h)
                    .map(|k| i64::from(w[c - k].to_u32()) - i64::from(w[c + k].to_u32()))
                    .sum();
                sum as f64
            };
            (gi(h + 1), gi(h), gi(h + 2))
        }
        None => (g(x), g(x - 1), g(x + 1)),
    };
    blais_rioux_crossing(x, a, c, [gl, g0, gr])
}

/// The zero crossing of the Blais-Rioux filter near pixel `x` from its values `g` at x − 1, x, x + 1 and the
/// neighbours `a` = f(x − 1), `c` = f(x + 1) that pick the side.
fn blais_rioux_crossing(x: isize, a: f64, c: f64, g: [f64; 3]) -> Option<f64> {
    let [gl, g0, gr] = g;
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
        let mut next = crate::test_rng(0x9e37_79b9);
        let mut peaks = Vec::new();
        let mut checked = 0;
        for _ in 0..300 {
            let line: Vec<u16> = (0..80)
                .map(|_| {
                    let r = next();
                    // Mostly background with bright runs: stripes, cliffs and plateaus.
                    if r % 7 < 2 {
                        (r >> 8) as u16
                    } else {
                        (r % 40) as u16
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

    #[test]
    fn tabled_logarithms_equal_ln() {
        let values = (-3..5000).map(f64::from).chain([
            0.25,
            0.5,
            0.75,
            1.5,
            4095.5,
            1e9,
            -1e9,
            f64::NAN,
            f64::INFINITY,
        ]);
        for v in values {
            let l = ln_level(ln_table(), v);
            assert_eq!(l.to_bits(), v.max(0.5).ln().to_bits(), "{v}");
        }
    }

    /// A one-pixel top at `top` whose region of interest is the whole line.
    fn peak_at(line: &[u16], top: usize) -> Peak {
        Peak {
            top_start: top,
            top_end: top,
            value: u32::from(line[top]),
            roi_left: 0,
            roi_right: line.len() - 1,
        }
    }

    #[test]
    fn gaussian_on_integer_levels_equals_the_formula() {
        // The integer-level path against the estimator as written in floating point, bit for bit, on random
        // lines with integer and fractional backgrounds and peaks at the ends.
        let mut next = crate::test_rng(0x1234_5678u32);
        let mut checked = 0;
        for case in 0..3000 {
            let line: Vec<u16> = (0..12).map(|_| (next() % 6000) as u16).collect();
            let top = (next() % 12) as usize;
            let p = peak_at(&line, top);
            let bg = if case % 3 == 0 {
                f64::from(next() % 3000) + 0.5
            } else {
                f64::from(next() % 3000)
            };
            let (a, b, c) = three(&line, top, bg);
            let (la, lb, lc) = (a.max(0.5).ln(), b.max(0.5).ln(), c.max(0.5).ln());
            let d = 0.5 * (la - lc) / (la - 2.0 * lb + lc);
            let want = (d.is_finite() && d.abs() <= 1.0).then_some(top as f64 + d);
            let got = gaussian(&line, &p, bg);
            assert_eq!(
                got.map(f64::to_bits),
                want.map(f64::to_bits),
                "{line:?} {top} {bg}"
            );
            checked += usize::from(want.is_some());
        }
        assert!(checked > 100, "{checked}");
    }

    #[test]
    fn integer_centre_of_mass_equals_the_floating_point_sums() {
        let mut next = crate::test_rng(0x5151_7a7au32);
        for case in 0..2000 {
            let line: Vec<u16> = (0..40).map(|_| (next() % 65536) as u16).collect();
            let (lo, hi) = ((next() % 40) as usize, (next() % 45) as usize);
            let bg = match case % 3 {
                0 => f64::from(next() % 65536),
                1 => f64::from(next() % 65536) + 0.25,
                _ => -1.0,
            };
            let (mut s, mut sx) = (0.0, 0.0);
            for (i, &q) in line.iter().enumerate().take(hi + 1).skip(lo) {
                let w = (f64::from(q) - bg).max(0.0);
                s += w;
                sx += w * i as f64;
            }
            let want = (s > 0.0).then(|| sx / s);
            let got = centre_of_mass(&line, lo, hi, bg);
            assert_eq!(
                got.map(f64::to_bits),
                want.map(f64::to_bits),
                "{lo}..={hi} over {bg}"
            );
        }
    }

    #[test]
    fn integer_blais_rioux_sums_equal_the_floating_point_ones() {
        let reference = |line: &[u16], p: &Peak, half: isize| {
            let g =
                |i: isize| -> f64 { (1..=half).map(|k| at(line, i - k) - at(line, i + k)).sum() };
            let x = p.center() as isize;
            let (a, c) = (at(line, x - 1), at(line, x + 1));
            blais_rioux_crossing(x, a, c, [g(x - 1), g(x), g(x + 1)])
        };
        let mut next = crate::test_rng(0x7777_1111u32);
        let mut checked = 0;
        for _ in 0..3000 {
            let line: Vec<u16> = (0..16).map(|_| (next() % 65536) as u16).collect();
            let top = (next() % 16) as usize;
            let p = peak_at(&line, top);
            for half in [2, 4] {
                let want = reference(&line, &p, half);
                let got = blais_rioux(&line, &p, half);
                assert_eq!(
                    got.map(f64::to_bits),
                    want.map(f64::to_bits),
                    "{line:?} {top}"
                );
                checked += usize::from(want.is_some());
            }
        }
        assert!(checked > 100, "{checked}");
    }
}
