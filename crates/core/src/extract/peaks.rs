//! Dominant peak locating (Wu, Lee & de Silva, section 4.1, eq. 4-6).
//!
//! A *peak* is a pixel after a rise (or flat) and before a fall; a *valley* a pixel after a fall and before a rise
//! (or flat). A peak is *dominant* when it stands more than the threshold above a valley on each side (eq. 4), the
//! highest such peak between two valleys representing the stripe. Its region of interest runs from the nearest
//! valley on the left to the nearest valley on the right that are each more than the threshold below it (eq. 5-6);
//! a valley may be flat on its far side (a quantised flat background has no strict fall).
//!
//! Implementation: one pass with hysteresis finds the dominant peaks exactly as eq. 4 defines them (the running
//! maximum is a dominant peak once the signal falls more than the threshold below it, having risen more than the
//! threshold above the running minimum before it). Background is skipped: no pixel at or below the line's minimum
//! plus the threshold can start a rise, so while looking for one the scan jumps to the next pixel above that
//! level; the running minimum over the skipped run is settled by its first pixel more than the threshold below the
//! next one (one vectorisable reduction over the run only when there is none). A flat top (saturation) is one peak
//! whose plateau is recorded. The valleys bounding each region of interest are found among the line's valley
//! candidates (pixels at most both neighbours), marked 16 at a time ([`Pixel::valley_marks`]).

use crate::image::Pixel;

/// One dominant peak on a scan line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Peak {
    /// First pixel of the peak's flat top.
    pub top_start: usize,
    /// Last pixel of the peak's flat top (equal to `top_start` without a plateau).
    pub top_end: usize,
    /// Peak value.
    pub value: u32,
    /// Left bound of the region of interest (a valley, eq. 6).
    pub roi_left: usize,
    /// Right bound of the region of interest (a valley, eq. 5).
    pub roi_right: usize,
}

impl Peak {
    /// The integer peak position: the middle of the flat top.
    pub fn center(&self) -> usize {
        (self.top_start + self.top_end) / 2
    }

    /// True when the top is a plateau of two or more equal pixels.
    pub fn is_plateau(&self) -> bool {
        self.top_end > self.top_start
    }
}

#[inline]
fn v<T: Pixel>(line: &[T], i: usize) -> u32 {
    line[i].to_u32()
}

/// Finds the dominant peaks of `line` whose prominence exceeds `threshold` and appends them to `out` (cleared
/// first), left to right.
pub fn dominant_peaks<T: Pixel>(line: &[T], threshold: u32, out: &mut Vec<Peak>) {
    dominant_peaks_impl(line, threshold, out, true);
}

/// The scan; `fast` false is the plain reference (no background skip, valleys found by walking), which the tests
/// hold the fast path to.
fn dominant_peaks_impl<T: Pixel>(line: &[T], threshold: u32, out: &mut Vec<Peak>, fast: bool) {
    out.clear();
    let n = line.len();
    if n < 3 {
        return;
    }
    // Mode: looking for a rise (min tracked) or for a fall (max tracked).
    let mut rising = false;
    let (mut mn, mut mx) = (v(line, 0), 0u32);
    let (mut top_start, mut top_end) = (0usize, 0usize);
    // No pixel at or below `level` can start a rise: a rise needs a value more than the threshold above the
    // running minimum, which is never below the line's minimum.
    let level = if fast {
        T::slice_min(line).saturating_add(threshold)
    } else {
        0
    };
    let mut i = 0;
    while i < n {
        if fast && !rising && v(line, i) <= level {
            // Jump to the next pixel above `level` (16 bytes per step, [`Pixel::first_above`]), folding the skipped
            // pixels into the running minimum. (Chunks reduced to their maximum measured slower: with 11 stripes in
            // 648 columns the background gaps are short. A falling flank's pixels above the level go the scalar way,
            // without a call.)
            let run = T::first_above(&line[i..], level).unwrap_or(n - i);
            if run > 0 {
                let gap = &line[i..i + run];
                i += run;
                if i >= n {
                    break;
                }
                // The running minimum only decides whether the pixel after the gap starts a rise (once rising it
                // is not read again before the next fall resets it): one skipped pixel more than the threshold
                // below that pixel is enough, and on a background one is usually the first. The whole gap's
                // minimum only when none is.
                let x = v(line, i);
                if x <= mn.saturating_add(threshold) {
                    let low = x.saturating_sub(threshold);
                    mn = match gap.iter().find(|p| p.to_u32() < low) {
                        Some(p) => p.to_u32(),
                        None => mn.min(T::slice_min(gap)),
                    };
                }
            }
        }
        let x = v(line, i);
        if rising {
            if x > mx {
                mx = x;
                top_start = i;
                top_end = i;
            } else if x == mx && top_end + 1 == i {
                top_end = i;
            } else if x + threshold < mx {
                out.push(Peak {
                    top_start,
                    top_end,
                    value: mx,
                    roi_left: 0,
                    roi_right: 0,
                });
                rising = false;
                mn = x;
            }
        } else if x < mn {
            mn = x;
        } else if x > mn.saturating_add(threshold) {
            rising = true;
            mx = x;
            top_start = i;
            top_end = i;
        }
        i += 1;
    }
    // Regions of interest: the nearest valleys more than the threshold below each peak (eq. 5-6), the fast way
    // testing 16 valley candidates at a time ([`Pixel::valley_marks`]).
    for k in 0..out.len() {
        let p = out[k];
        let limit = p.value.saturating_sub(threshold);
        let left_stop = if k > 0 { out[k - 1].top_end } else { 0 };
        let right_stop = if k + 1 < out.len() {
            out[k + 1].top_start
        } else {
            n - 1
        };
        (out[k].roi_left, out[k].roi_right) = match fast {
            true => (
                marked_valley_left(line, p.top_start, left_stop, limit),
                marked_valley_right(line, p.top_end, right_stop, limit),
            ),
            false => (
                nearest_valley_left(line, p.top_start, left_stop, limit),
                nearest_valley_right(line, p.top_end, right_stop, limit),
            ),
        };
    }
}

/// [`nearest_valley_left`] over the valley candidates, 16 at a time: the last marked pixel in `stop + 1..from`
/// below `limit`, else `stop`.
fn marked_valley_left<T: Pixel>(line: &[T], from: usize, stop: usize, limit: u32) -> usize {
    // Candidates lie in stop + 1..end; each block holds the 16 pixels before `end` (fewer at the line's start).
    let mut end = from;
    while end > stop + 1 {
        let start = end.saturating_sub(16).max(stop + 1);
        // Bits of start..end.
        let mut m = T::valley_marks(line, start) & ((1u32 << (end - start)) - 1);
        while m != 0 {
            let k = 31 - m.leading_zeros() as usize;
            if v(line, start + k) < limit {
                return start + k;
            }
            m &= !(1 << k);
        }
        end = start;
    }
    stop
}

/// [`nearest_valley_right`] over the valley candidates, 16 at a time: the first marked pixel in `from + 1..stop`
/// below `limit`, else `stop`.
fn marked_valley_right<T: Pixel>(line: &[T], from: usize, stop: usize, limit: u32) -> usize {
    let mut start = from + 1;
    while start < stop {
        let len = (stop - start).min(16);
        let mut m = T::valley_marks(line, start) & ((1u32 << len) - 1);
        while m != 0 {
            let k = m.trailing_zeros() as usize;
            if v(line, start + k) < limit {
                return start + k;
            }
            m &= m - 1;
        }
        start += 16;
    }
    stop
}

/// Nearest valley left of `from` (down to `stop`) whose value is below `limit`; `stop` when none is.
fn nearest_valley_left<T: Pixel>(line: &[T], from: usize, stop: usize, limit: u32) -> usize {
    let mut i = from;
    while i > stop {
        i -= 1;
        let x = v(line, i);
        if x < limit {
            // A valley: a fall (or flat) into i, then a rise or flat out of it (towards the peak). Allowing the
            // flat on the far side, unlike the paper's strict fall, ends the search on a quantised flat background
            // instead of running on to the previous stripe.
            let fell = i == 0 || v(line, i - 1) >= x;
            let rises = v(line, i + 1) >= x;
            if (fell && rises) || i == stop {
                return i;
            }
        }
    }
    stop
}

/// Nearest valley right of `from` (up to `stop`) whose value is below `limit`; `stop` when none is.
fn nearest_valley_right<T: Pixel>(line: &[T], from: usize, stop: usize, limit: u32) -> usize {
    let n = line.len();
    let mut i = from;
    while i < stop {
        i += 1;
        let x = v(line, i);
        if x < limit {
            let fell = v(line, i - 1) >= x;
            let rises = i + 1 >= n || v(line, i + 1) >= x;
            if (fell && rises) || i == stop {
                return i;
            }
        }
    }
    stop
}

/// Noise of a scan line in grey levels, from the median absolute first difference (robust to the stripes:
/// sigma = 1.4826 * median|f(i+1) - f(i)| / sqrt(2)). Uses a histogram, so it costs one pass.
pub fn line_noise<T: Pixel>(line: &[T], hist: &mut Vec<u32>) -> f64 {
    if line.len() < 2 {
        return 0.0;
    }
    // Differences beyond this are stripes, not noise; a median beyond it would not be noise either.
    const BINS: usize = 256;
    // Four histograms, filled in turn and summed: consecutive differences of a noisy background mostly fall in the
    // same few bins, and one histogram makes each increment wait for the last one's store.
    hist.clear();
    hist.resize(4 * BINS, 0);
    let (h, rest) = hist.split_at_mut(BINS);
    let (h1, rest) = rest.split_at_mut(BINS);
    let (h2, h3) = rest.split_at_mut(BINS);
    let bin = |i: usize| (line[i].to_u32().abs_diff(line[i + 1].to_u32()) as usize).min(BINS - 1);
    // Differences i = 0..n - 1, four at a time, then the rest.
    let n = line.len() - 1;
    let mut i = 0;
    while i + 4 <= n {
        h[bin(i)] += 1;
        h1[bin(i + 1)] += 1;
        h2[bin(i + 2)] += 1;
        h3[bin(i + 3)] += 1;
        i += 4;
    }
    for i in i..n {
        h[bin(i)] += 1;
    }
    let half = (line.len() - 1).div_ceil(2) as u32;
    let mut acc = 0;
    for d in 0..BINS {
        acc += h[d] + h1[d] + h2[d] + h3[d];
        if acc >= half {
            return 1.4826 * d as f64 / std::f64::consts::SQRT_2;
        }
    }
    0.0
}

#[cfg(test)]
mod tests {
    use super::*;

    fn peaks(line: &[u8], t: u32) -> Vec<Peak> {
        let mut out = Vec::new();
        dominant_peaks(line, t, &mut out);
        out
    }

    #[test]
    fn the_papers_figure_4_kind_of_line() {
        // Two stripes, one with a small noise bump on its flank that must not become a peak.
        let line = [
            5, 6, 5, 20, 60, 100, 90, 95, 40, 10, 6, 5, 7, 5, 30, 80, 30, 6, 5, 5,
        ];
        let p = peaks(&line, 20);
        assert_eq!(p.len(), 2);
        assert_eq!((p[0].top_start, p[0].value), (5, 100));
        assert_eq!((p[1].top_start, p[1].value), (15, 80));
        // ROI: nearest valleys more than 20 below the peak
        assert_eq!((p[0].roi_left, p[0].roi_right), (2, 11));
        assert_eq!((p[1].roi_left, p[1].roi_right), (13, 18));
    }

    #[test]
    fn plateaus_become_one_peak_and_small_bumps_none() {
        let mut line = vec![3u8; 100];
        for x in &mut line[40..47] {
            *x = 255;
        }
        line[39] = 120;
        line[47] = 120;
        line[70] = 12; // below threshold
        let p = peaks(&line, 20);
        assert_eq!(p.len(), 1);
        assert_eq!((p[0].top_start, p[0].top_end, p[0].center()), (40, 46, 43));
        assert!(p[0].is_plateau());
        assert!(peaks(&[0u8; 10], 1).is_empty());
        assert!(peaks(&[255u8; 100], 1).is_empty(), "all saturated: no peak");
        assert!(peaks(&[1u8, 200], 1).is_empty());
    }

    #[test]
    fn skipping_and_marked_valleys_change_nothing() {
        let mut rng = 12345u32;
        let mut next = || {
            rng = rng.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            rng >> 8
        };
        for case in 0..2000 {
            // Lengths across the 16-pixel blocks of valley marks; some bumps broad enough that their valleys lie
            // several blocks away from the top.
            let n = 3 + (next() % 400) as usize;
            let t = [1u32, 5, 15, 40][case % 4];
            let mut line = vec![0u16; n];
            for x in line.iter_mut() {
                *x = (next() % 12) as u16;
            }
            for _ in 0..(case % 7) {
                let c = (next() % n as u32) as usize;
                let a = 20 + (next() % 230) as u16;
                let broad = next() % 4 == 0;
                let w = if broad {
                    1 + (next() % 150) as usize
                } else {
                    1 + (next() % 6) as usize
                };
                for d in 0..w {
                    let fall = if broad { a / 160 } else { a / 8 };
                    for x in [c + d, c.wrapping_sub(d)] {
                        if x < n {
                            line[x] = line[x].max(a.saturating_sub(fall * d as u16));
                        }
                    }
                }
            }
            let line8: Vec<u8> = line.iter().map(|&x| x.min(255) as u8).collect();
            let (mut fast, mut slow) = (Vec::new(), Vec::new());
            dominant_peaks_impl(&line8, t, &mut fast, true);
            dominant_peaks_impl(&line8, t, &mut slow, false);
            assert_eq!(fast, slow, "u8, case {case}");
            dominant_peaks_impl(&line, t, &mut fast, true);
            dominant_peaks_impl(&line, t, &mut slow, false);
            assert_eq!(fast, slow, "u16, case {case}");
            for p in &fast {
                assert!(u32::from(line[p.roi_left]) + t < p.value || p.roi_left == 0);
                assert!(u32::from(line[p.roi_right]) + t < p.value || p.roi_right == n - 1);
                assert!(p.roi_left <= p.top_start && p.top_end <= p.roi_right);
                assert!(
                    line[p.top_start..=p.top_end]
                        .iter()
                        .all(|&x| u32::from(x) == p.value)
                );
            }
        }
    }

    #[test]
    fn noise_estimate_is_robust_to_stripes() {
        let mut hist = Vec::new();
        let flat = vec![10u8; 648];
        assert_eq!(line_noise(&flat, &mut hist), 0.0);
        let mut line = vec![0u8; 648];
        for (i, x) in line.iter_mut().enumerate() {
            *x = if i % 2 == 0 { 10 } else { 12 };
        }
        line[300..305].copy_from_slice(&[100, 200, 250, 200, 100]);
        let s = line_noise(&line, &mut hist);
        assert!(
            (s - 1.4826 * 2.0 / std::f64::consts::SQRT_2).abs() < 1e-9,
            "{s}"
        );
    }

    #[test]
    fn noise_is_the_median_difference() {
        // The histogram's median against sorting, on random lines of every length and spread.
        let mut next = crate::test_rng(0x0bad_5eedu32);
        let mut hist = Vec::new();
        for case in 0..500u32 {
            let len = 2 + (next() % 300) as usize;
            let spread = [3, 20, 400, 65535][(case % 4) as usize];
            let line: Vec<u16> = (0..len).map(|_| (next() % spread) as u16).collect();
            let mut diffs: Vec<u32> = line
                .windows(2)
                .map(|w| u32::from(w[0].abs_diff(w[1])).min(255))
                .collect();
            diffs.sort_unstable();
            let median = diffs[(len - 1).div_ceil(2) - 1];
            let want = 1.4826 * f64::from(median) / std::f64::consts::SQRT_2;
            assert_eq!(line_noise(&line, &mut hist), want, "{line:?}");
        }
    }
}
