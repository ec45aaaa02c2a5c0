//! The local evidence a stripe point is judged by: the scan-line signal summed along the stripe over a few
//! neighbouring scan lines, and the noise of that signal, estimated per tile of the frame.
//!
//! **Along-line sum.** A stripe is a line that crosses the scan lines; noise is independent from pixel to pixel.
//! The sum `D(i, k) = Σ_{j=-r..r} f(i, k + j)` over `2r + 1` neighbouring scan lines (clamped at the frame's edges)
//! adds the stripe's light coherently and the noise incoherently, so the signal-to-noise ratio grows by
//! `sqrt(2r + 1)`. For a stripe crossing the lines at a slope `s` (pixels per line) the sum is a symmetric blend of
//! profiles shifted by `-r s .. r s`: its centre is the centre on line `k` for any straight stripe (no bias to first
//! order), and a curved stripe is biased by `r(r+1)/6` times its second difference — below 0.01 px for r = 1 unless
//! the stripe bends by more than 0.03 px per line per line.
//!
//! **Across the line, the optics' width.** A stripe is at least as wide as the optics blur it (a standard deviation
//! of a pixel or more); a noise spike is one pixel. Peaks are *found* on the sum smoothed across the line with the
//! binomial kernel `[1, 2, 1]` (a Gaussian of 0.71 px), which keeps nine tenths of a stripe's peak and halves a
//! spike's (the noise's standard deviation falls to `sqrt(6) / 4` of its value); centres are *estimated* on the
//! unsmoothed sum, so the estimators see the stripe's own profile.
//!
//! **Local noise.** The frame is cut into square tiles of [`DEFAULT_NOISE_TILE_PX`] pixels; in each, the standard
//! deviation of the detection signal `S` (the sum smoothed across the line) is estimated from the median absolute
//! difference of values [`NOISE_LAG`] apart, along the scan lines and across them (`sigma = 1.4826 median|ΔS| /
//! sqrt(2)`), interpolated within the integer bins so that a noise of one or two grey levels is measured to a tenth
//! of a level. Values that far apart share no pixel, so the estimate holds for noise the camera correlates over
//! neighbouring pixels as well as for independent noise. Stripes and printed edges along the lines make large
//! differences along them, edges across the lines across them; the median ignores them while they are fewer than
//! half, and the tile takes the lower of the two estimates. Between tile centres the estimate is interpolated
//! bilinearly. The floor is the quantisation noise of the smoothed sum, `sqrt(6 (2r + 1) / 12)` levels.

use crate::image::{ImageView, Pixel};

/// Default side of a noise tile, pixels: large enough for a robust median (the 32 x 32 pixels, sampled in pairs of
/// lines every [`NOISE_LINE_STEP`] lines, give 464 differences along the lines and 256 across them; neighbouring
/// differences share pixels, and the tiles of a frame of even noise read within about 20 % of it), small enough to
/// follow ambient light and vignetting.
pub const DEFAULT_NOISE_TILE_PX: usize = 32;
/// Lag of the differences the noise is read from, pixels along a scan line and scan lines across them: values of
/// the detection signal this far apart share no pixel (the kernel `[1, 2, 1]` spans three pixels, the along-line sum
/// three lines), so for independent pixels their difference has twice the signal's variance, and where a camera
/// correlates neighbouring pixels (demosaicing, compression, denoising) the difference still sees all of the noise
/// at the scale peaks are found at (a first difference of the raw signal reads such noise several times too low,
/// and its chance peaks pass as stripes).
pub const NOISE_LAG: usize = 3;
/// Scan lines sampled for the noise: one every this many within a tile (in pairs [`NOISE_LAG`] apart).
pub const NOISE_LINE_STEP: usize = 4;

/// How the along-line sum is held: the sum itself when its smoothed form fits 16 bits, else the sum over the least
/// divisor that makes it fit (frames whose values reach past `65535 / (4 (2r + 1))`, 5461 for three lines: deep
/// 16-bit frames, whose noise is then still many levels of the held sum).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SumScale {
    /// Scan lines summed, `2r + 1`.
    pub lines: usize,
    /// The divisor applied to the sum (1 when it fits).
    pub divisor: u32,
}

impl SumScale {
    /// How many times one scan line's grey levels the held sum is.
    pub fn gain(&self) -> f64 {
        self.lines as f64 / f64::from(self.divisor)
    }

    /// How many times one scan line's grey levels the smoothed sum (the detection signal) is.
    pub fn detect_gain(&self) -> f64 {
        f64::from(SMOOTH_GAIN) * self.gain()
    }
}

/// Sum of the weights of the across-line kernel `[1, 2, 1]`.
pub const SMOOTH_GAIN: u32 = 4;
/// What the kernel `[1, 2, 1]` does to the standard deviation of independent noise: `sqrt(1 + 4 + 1)`.
pub const SMOOTH_NOISE_GAIN: f64 = 2.449_489_742_783_178;

/// The detection signal: `out[i] = d[i-1] + 2 d[i] + d[i+1]`, the ends replicated.
pub fn smoothed(d: &[u16], out: &mut Vec<u16>) {
    out.clear();
    let n = d.len();
    if n == 0 {
        return;
    }
    let at = |i: usize| u32::from(d[i]);
    let cap = |v: u32| v.min(u32::from(u16::MAX)) as u16;
    // The ends replicated; the interior in one pass over windows, which vectorises.
    out.push(cap(3 * at(0) + at(1.min(n - 1))));
    out.extend(
        d.windows(3)
            .map(|w| cap(u32::from(w[0]) + 2 * u32::from(w[1]) + u32::from(w[2]))),
    );
    if n > 1 {
        out.push(cap(at(n - 2) + 3 * at(n - 1)));
    }
}

/// The sum scale for a frame whose brightest pixel is `max`.
pub fn sum_scale(lines: usize, max: u32) -> SumScale {
    let lines = lines.max(1);
    let top = u64::from(max.max(1)) * lines as u64 * u64::from(SMOOTH_GAIN);
    SumScale {
        lines,
        divisor: top.div_ceil(u64::from(u16::MAX)).max(1) as u32,
    }
}

/// Writes the along-line sum of scan line `k` into `out` (cleared first).
pub fn summed_line<T: Pixel>(
    img: &ImageView<'_, T>,
    rows_axis: bool,
    k: usize,
    scale: SumScale,
    acc: &mut Vec<u32>,
    out: &mut Vec<u16>,
) {
    let (w, h) = (img.width(), img.height());
    let (len, count) = if rows_axis { (w, h) } else { (h, w) };
    out.clear();
    if count == 0 || len == 0 {
        return;
    }
    let r = (scale.lines / 2) as isize;
    acc.clear();
    acc.resize(len, 0);
    for j in -r..=r {
        let kk = (k as isize + j).clamp(0, count as isize - 1) as usize;
        if rows_axis {
            for (a, p) in acc.iter_mut().zip(img.row(kk)) {
                *a += p.to_u32();
            }
        } else {
            for (i, a) in acc.iter_mut().enumerate() {
                *a += img.get(kk, i).map_or(0, |p| p.to_u32());
            }
        }
    }
    let d = scale.divisor;
    if d == 1 {
        out.extend(acc.iter().map(|&a| a.min(u32::from(u16::MAX)) as u16));
    } else {
        out.extend(
            acc.iter()
                .map(|&a| ((a + d / 2) / d).min(u32::from(u16::MAX)) as u16),
        );
    }
}

/// Quantile of the absolute differences the noise is read from: the median. (The lower quartile resists denser
/// stripes but reads the clipped, quantised noise of a black belt a third lower than its tails, and more chance
/// peaks then pass: measured on the validation frames, false points 1.2 % against 0.9 % with the median.)
pub const NOISE_QUANTILE: f64 = 0.5;
/// The median of |N(0, 1)|: `Φ^-1(0.75)`.
const HALF_NORMAL_QUANTILE: f64 = 0.674_490;

/// The robust standard deviation of a zero-mean variable from the absolute first differences of a signal: their
/// median ([`NOISE_QUANTILE`]) over that of a half-normal variable, interpolated within the integer bins (`diffs` may
/// be reordered).
pub fn sigma_from_differences(diffs: &mut [u16]) -> f64 {
    if diffs.is_empty() {
        return 0.0;
    }
    let half = ((diffs.len() as f64 * NOISE_QUANTILE) as usize).min(diffs.len() - 1);
    // The order statistic and the counts below and at it, from a histogram of the small values where the quantile
    // lies among them (noise differences are a few levels; a stripe's are the few large ones), else by selection:
    // the same three numbers either way.
    const BINS: usize = 64;
    let mut hist = [0u32; BINS];
    for &d in diffs.iter() {
        if usize::from(d) < BINS {
            hist[usize::from(d)] += 1;
        }
    }
    let mut cum = 0usize;
    let mut found = None;
    for (v, &c) in hist.iter().enumerate() {
        if cum + c as usize > half {
            found = Some((v as u16, cum, c as usize));
            break;
        }
        cum += c as usize;
    }
    let (m, below, equal) = match found {
        Some(f) => f,
        None => {
            let m = *diffs.select_nth_unstable(half).1;
            let (mut below, mut equal) = (0usize, 0usize);
            for &d in diffs.iter() {
                if d < m {
                    below += 1;
                } else if d == m {
                    equal += 1;
                }
            }
            (m, below, equal)
        }
    };
    // Bin m covers [m - 0.5, m + 0.5) (bin 0: [0, 0.5)); the quantile is where its share of the counts is reached.
    let target = diffs.len() as f64 * NOISE_QUANTILE;
    let frac = ((target - below as f64) / equal.max(1) as f64).clamp(0.0, 1.0);
    let median = if m == 0 {
        0.5 * frac
    } else {
        f64::from(m) - 0.5 + frac
    };
    median / HALF_NORMAL_QUANTILE / std::f64::consts::SQRT_2
}

/// Appends `diff(i)` for positions `0..n` of a line to the list of the tile (`tile` positions wide) each lies in,
/// tile by tile, each tile's in the order of the line.
fn gather_by_tile(tiles: &mut [Vec<u16>], tile: usize, n: usize, diff: impl Fn(usize) -> u16) {
    for (xt, into) in tiles.iter_mut().enumerate() {
        let (a, b) = (xt * tile, ((xt + 1) * tile).min(n));
        if a >= b {
            break;
        }
        into.extend((a..b).map(&diff));
    }
}

/// Buffers [`NoiseMap::estimate`] reuses from frame to frame.
#[derive(Debug, Clone, Default)]
pub struct NoiseScratch {
    acc: Vec<u32>,
    sum: Vec<u16>,
    detect: Vec<u16>,
    detect_b: Vec<u16>,
    along: Vec<Vec<u16>>,
    across: Vec<Vec<u16>>,
}

/// The noise of a frame's summed signal, per tile.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct NoiseMap {
    tile_px: usize,
    /// Tiles along the scan lines and across them.
    tiles: (usize, usize),
    sigma: Vec<f32>,
    line_min: Vec<f32>,
}

impl NoiseMap {
    /// Estimates the map of `img` (scan lines along rows when `rows_axis`), reusing the buffers.
    pub fn estimate<T: Pixel>(
        &mut self,
        img: &ImageView<'_, T>,
        rows_axis: bool,
        scale: SumScale,
        tile_px: usize,
        bufs: &mut NoiseScratch,
    ) {
        let (w, h) = (img.width(), img.height());
        let (len, count) = if rows_axis { (w, h) } else { (h, w) };
        let tile = tile_px.max(4);
        self.tile_px = tile;
        let (tx, ty) = (len.div_ceil(tile).max(1), count.div_ceil(tile).max(1));
        self.tiles = (tx, ty);
        self.sigma.clear();
        self.sigma.resize(tx * ty, 0.0);
        // Quantisation: 1/12 level squared per pixel, times the sum of the squared weights (6 per line summed).
        let floor = (6.0 * scale.lines as f64 / 12.0).sqrt() / f64::from(scale.divisor);
        let NoiseScratch {
            acc,
            sum,
            detect,
            detect_b,
            along,
            across,
        } = bufs;
        along.resize_with(tx, Vec::new);
        across.resize_with(tx, Vec::new);
        for yt in 0..ty {
            for d in along.iter_mut().chain(across.iter_mut()) {
                d.clear();
            }
            let (k0, k1) = (yt * tile, ((yt + 1) * tile).min(count));
            let step = NOISE_LINE_STEP.min((k1 - k0).max(1));
            // Pairs of lines NOISE_LAG apart, a pair every step.
            for k in (k0 + step / 2..k1).step_by(step) {
                let kb = (k + NOISE_LAG).min(count - 1);
                summed_line(img, rows_axis, k, scale, acc, sum);
                smoothed(sum, detect);
                summed_line(img, rows_axis, kb, scale, acc, sum);
                smoothed(sum, detect_b);
                for line in [&*detect, &*detect_b] {
                    let n = line.len().saturating_sub(NOISE_LAG);
                    gather_by_tile(along, tile, n, |i| line[i].abs_diff(line[i + NOISE_LAG]));
                }
                if kb != k {
                    let n = detect.len().min(detect_b.len());
                    gather_by_tile(across, tile, n, |i| detect[i].abs_diff(detect_b[i]));
                }
            }
            for xt in 0..tx {
                let a = sigma_from_differences(&mut along[xt]);
                let c = sigma_from_differences(&mut across[xt]);
                // Each kind of structure raises one: stripes and printed edges along the scan lines the first,
                // edges across them the second. The lower is the noise.
                let s = match (along[xt].is_empty(), across[xt].is_empty()) {
                    (false, false) => a.min(c),
                    (false, true) => a,
                    (true, false) => c,
                    (true, true) => 0.0,
                };
                self.sigma[yt * tx + xt] = s.max(floor) as f32;
            }
        }
        // Tiles with no sample (a frame narrower than two pixels) take the floor.
        for s in self.sigma.iter_mut() {
            if s.is_nan() || *s <= 0.0 {
                *s = floor as f32;
            }
        }
        self.line_min.clear();
        self.line_min.extend((0..count).map(|k| {
            let yt = (k / tile).min(ty - 1);
            self.sigma[yt * tx..(yt + 1) * tx]
                .iter()
                .copied()
                .fold(f32::INFINITY, f32::min)
        }));
    }

    /// The noise at position `x` of scan line `k`, bilinear between tile centres.
    pub fn at(&self, x: f64, k: usize) -> f64 {
        let (tx, ty) = self.tiles;
        if self.sigma.is_empty() {
            return 0.0;
        }
        let t = self.tile_px as f64;
        let fx = ((x + 0.5) / t - 0.5).clamp(0.0, (tx - 1) as f64);
        let fy = ((k as f64 + 0.5) / t - 0.5).clamp(0.0, (ty - 1) as f64);
        let (x0, y0) = (fx.floor() as usize, fy.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(tx - 1), (y0 + 1).min(ty - 1));
        let (ax, ay) = (fx - x0 as f64, fy - y0 as f64);
        let s = |xi: usize, yi: usize| f64::from(self.sigma[yi * tx + xi]);
        (s(x0, y0) * (1.0 - ax) + s(x1, y0) * ax) * (1.0 - ay)
            + (s(x0, y1) * (1.0 - ax) + s(x1, y1) * ax) * ay
    }

    /// The smallest tile noise on scan line `k` (the level below which no point of the line can be accepted).
    pub fn line_min(&self, k: usize) -> f64 {
        self.line_min.get(k).map_or(0.0, |&s| f64::from(s))
    }

    /// The median tile noise of the frame.
    pub fn median(&self) -> f64 {
        let mut v = self.sigma.clone();
        if v.is_empty() {
            return 0.0;
        }
        let mid = v.len() / 2;
        f64::from(*v.select_nth_unstable_by(mid, f32::total_cmp).1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::Image;
    use proptest::prelude::*;

    proptest! {
        /// The histogram's order statistic and counts are the selection's, wherever the quantile falls.
        #[test]
        fn the_noise_quantile_is_the_selections(mut diffs in proptest::collection::vec(0u16..200, 1..300)) {
            let half = ((diffs.len() as f64 * NOISE_QUANTILE) as usize).min(diffs.len() - 1);
            let mut sorted = diffs.clone();
            sorted.sort_unstable();
            let m = sorted[half];
            let below = sorted.iter().filter(|&&d| d < m).count();
            let equal = sorted.iter().filter(|&&d| d == m).count();
            let target = diffs.len() as f64 * NOISE_QUANTILE;
            let frac = ((target - below as f64) / equal.max(1) as f64).clamp(0.0, 1.0);
            let median = if m == 0 { 0.5 * frac } else { f64::from(m) - 0.5 + frac };
            let expected = median / HALF_NORMAL_QUANTILE / std::f64::consts::SQRT_2;
            prop_assert_eq!(sigma_from_differences(&mut diffs), expected);
        }
    }

    fn gaussian_noise(seed: &mut u64) -> f64 {
        // Box-Muller from a 64-bit LCG.
        let mut u = || {
            *seed = seed
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            ((*seed >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        let (a, b) = (u(), u());
        (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
    }

    #[test]
    fn the_noise_of_each_region_is_measured_and_stripes_only_raise_it() {
        // Left half noise 1.5 levels, right half 4 levels, over a background of 30; stripes every 40 px in the
        // lower half only.
        let (w, h) = (256usize, 128usize);
        let mut seed = 3u64;
        let mut img = Image::<u8>::new(w, h);
        for y in 0..h {
            for x in 0..w {
                let s = if x < w / 2 { 1.5 } else { 4.0 };
                let stripe = if y >= h / 2 {
                    120.0 * (-0.5 * (((x % 40) as f64 - 20.0) / 1.2).powi(2)).exp()
                } else {
                    0.0
                };
                let v = 30.0 + stripe + s * gaussian_noise(&mut seed);
                img.data_mut()[y * w + x] = v.round().clamp(0.0, 255.0) as u8;
            }
        }
        let mut map = NoiseMap::default();
        let scale = sum_scale(3, 255);
        assert_eq!(scale.detect_gain(), 12.0);
        let mut bufs = Default::default();
        map.estimate(&img.view(), true, scale, 32, &mut bufs);
        // The sum of three lines smoothed by [1, 2, 1] has sqrt(3 * 6) times the noise of one.
        let s3 = 18f64.sqrt();
        let (left, right) = (map.at(20.0, 16) / s3, map.at(236.0, 16) / s3);
        // The median of 248 differences has a standard error of 7 %; rounding adds 1/12 of a level squared.
        assert!((left - 1.53).abs() < 0.25, "left {left}");
        assert!((right - 4.0).abs() < 0.6, "right {right}");
        assert!(map.line_min(16) <= left * s3 + 1e-9);
        // Where stripe flanks are 15 % of the differences the median reads high (conservative), by less than half.
        let (left, right) = (map.at(20.0, 112) / s3, map.at(236.0, 112) / s3);
        assert!(left > 1.4 && left < 1.5 * 1.5, "left with stripes {left}");
        assert!(
            right > 3.8 && right < 4.0 * 1.5,
            "right with stripes {right}"
        );
    }

    #[test]
    fn the_interpolated_median_of_differences_recovers_small_noise() {
        let mut seed = 11u64;
        for sigma in [0.7, 1.0, 2.0, 3.0] {
            let line: Vec<i64> = (0..20_000)
                .map(|_| (50.0 + sigma * gaussian_noise(&mut seed)).round() as i64)
                .collect();
            let mut d: Vec<u16> = line
                .windows(2)
                .map(|p| (p[0] - p[1]).unsigned_abs() as u16)
                .collect();
            let s = sigma_from_differences(&mut d);
            // Rounding adds 1/12 of a level squared.
            let expected = (sigma * sigma + 1.0 / 12.0).sqrt();
            assert!(
                (s - expected).abs() < 0.08 * expected,
                "{sigma}: {s} vs {expected}"
            );
        }
    }

    #[test]
    fn sums_that_overflow_16_bits_are_held_as_means() {
        assert_eq!(sum_scale(3, 255).divisor, 1);
        // 60,000 x 3 x 4 / 65,535 = 10.99: the smoothed sum over 11 fits, and saturated pixels stay distinct.
        assert_eq!(sum_scale(3, 60_000).divisor, 11);
        assert_eq!(sum_scale(3, 65_535).divisor, 12);
        assert_eq!(sum_scale(3, 5_000).divisor, 1);
        assert_eq!(sum_scale(3, 5_461).divisor, 1);
        assert_eq!(sum_scale(3, 5_462).divisor, 2);
        let mut s = Vec::new();
        smoothed(&[0, 4, 0, 1], &mut s);
        assert_eq!(s, vec![4, 8, 5, 3]);
        let img = Image::<u16>::from_vec(2, 3, vec![60_000, 1, 60_000, 2, 60_000, 3]).expect("img");
        let (mut acc, mut out) = (Vec::new(), Vec::new());
        summed_line(
            &img.view(),
            true,
            1,
            sum_scale(3, 60_000),
            &mut acc,
            &mut out,
        );
        // (3 x 60,000) / 11 and (1 + 2 + 3) / 11, rounded.
        assert_eq!(out, vec![16_364, 1]);
        let mut det = Vec::new();
        smoothed(&[u16::MAX / 4; 3], &mut det);
        assert!(det.iter().all(|&v| v == 65_532));
        summed_line(&img.view(), true, 0, sum_scale(3, 3), &mut acc, &mut out);
        // Clamped at the edge: rows 0, 0, 1.
        assert_eq!(out[1], 1 + 1 + 2);
    }
}
