//! Steger's unbiased line detector (C. Steger, IEEE PAMI 20(2), 1998), 1-D along the scan line and full 2-D.
//!
//! Derivatives come from pixel-integrated Gaussian-derivative kernels at scale `s`: the response of pixel `j` to
//! the n-th derivative at `x` is the integral over the pixel of G⁽ⁿ⁾(x − u), i.e. a difference of G⁽ⁿ⁻¹⁾ at the
//! pixel's edges, so the kernels are exact for a piecewise-constant image. The scale follows the stripe's width:
//! `s = max(MIN_SCALE, w / √3)` for a stripe of half-width `w` (Steger's condition for a bar profile), rounded to
//! [`SCALE_STEP`] so kernels are computed once per scale.

use crate::image::Pixel;

/// Smallest scale used, pixels.
pub const MIN_SCALE: f64 = 0.8;
/// Scales are rounded to multiples of this, pixels.
pub const SCALE_STEP: f64 = 0.1;
/// Largest scale used, pixels.
pub const MAX_SCALE: f64 = 8.0;

/// Sub-pixel positions per pixel at which 1-D derivative kernels are tabulated.
pub const SUBPIXEL_STEPS: usize = 64;

/// Pixel-integrated kernels at one scale: smoothing, first and second derivative, for offsets −r..=r; and the
/// first and second derivative kernels for evaluation points between pixel centres (1/[`SUBPIXEL_STEPS`] apart).
#[derive(Debug, Clone)]
pub struct Kernels {
    /// Radius in pixels.
    pub radius: usize,
    /// Smoothing (sums to 1).
    pub d0: Vec<f64>,
    /// First derivative.
    pub d1: Vec<f64>,
    /// Second derivative.
    pub d2: Vec<f64>,
    /// For sub-pixel offset o = i/SUBPIXEL_STEPS − 0.5, the first and second derivative kernels at x + o.
    shifted: Vec<(Vec<f64>, Vec<f64>)>,
}

fn gauss(u: f64, s: f64) -> f64 {
    (-0.5 * (u / s).powi(2)).exp() / (s * (2.0 * std::f64::consts::PI).sqrt())
}

impl Kernels {
    /// Kernels at scale `s`: entry k (offset k − r) is the weight of pixel x − (k − r) for the derivative at x.
    pub fn new(s: f64) -> Self {
        let radius = (3.5 * s).ceil() as usize + 1;
        let mut d0 = Vec::with_capacity(2 * radius + 1);
        let mut d1 = Vec::with_capacity(2 * radius + 1);
        let mut d2 = Vec::with_capacity(2 * radius + 1);
        let g1 = |u: f64| -u / (s * s) * gauss(u, s);
        for k in -(radius as isize)..=radius as isize {
            let u = k as f64;
            d0.push(gauss(u, s));
            d1.push(gauss(u + 0.5, s) - gauss(u - 0.5, s));
            d2.push(g1(u + 0.5) - g1(u - 0.5));
        }
        let sum: f64 = d0.iter().sum();
        d0.iter_mut().for_each(|w| *w /= sum);
        // Truncation leaves the second-derivative kernel a small non-zero sum; a flat signal must give zero.
        let zero_sum = |d: &mut Vec<f64>| {
            let mean = d.iter().sum::<f64>() / d.len() as f64;
            d.iter_mut().for_each(|w| *w -= mean);
        };
        zero_sum(&mut d2);
        let shifted = (0..=SUBPIXEL_STEPS)
            .map(|i| {
                let o = i as f64 / SUBPIXEL_STEPS as f64 - 0.5;
                let mut a = Vec::with_capacity(2 * radius + 1);
                let mut b = Vec::with_capacity(2 * radius + 1);
                for k in -(radius as isize)..=radius as isize {
                    let u = k as f64 + o;
                    a.push(gauss(u + 0.5, s) - gauss(u - 0.5, s));
                    b.push(g1(u + 0.5) - g1(u - 0.5));
                }
                zero_sum(&mut a);
                zero_sum(&mut b);
                (a, b)
            })
            .collect();
        Self {
            radius,
            d0,
            d1,
            d2,
            shifted,
        }
    }

    /// First and second derivative of the smoothed line at `x` (any real position), and the position they are
    /// evaluated at (`x` on the grid of [`SUBPIXEL_STEPS`]).
    fn derivatives(&self, f: &impl Fn(isize) -> f64, x: f64) -> (f64, f64, f64) {
        let (xi, step) = grid_point(x);
        let (a, b) = &self.shifted[step];
        let r = self.radius as isize;
        let (mut r1, mut r2, mut mag) = (0.0, 0.0, 0.0);
        for j in -r..=r {
            let v = f(xi as isize - j);
            let idx = (j + r) as usize;
            r1 += v * a[idx];
            r2 += v * b[idx];
            mag += (v * b[idx]).abs();
        }
        finish(r1, r2, mag, xi, step)
    }

    /// [`Kernels::derivatives`] at evaluation point (`xi`, `step`) of a kernel window lying inside `line`: the
    /// pixels read straight from the line, without clamping (the same values in the same order, so the same sums
    /// to the bit). `None` when the window does not lie inside the line.
    #[inline]
    fn derivatives_inside<T: Pixel>(
        &self,
        line: &[T],
        xi: f64,
        step: usize,
    ) -> Option<(f64, f64, f64)> {
        let r = self.radius;
        let lo = (xi as isize).checked_sub(r as isize)?;
        let w = line.get(usize::try_from(lo).ok()?..)?.get(..2 * r + 1)?;
        let (a, b) = &self.shifted[step];
        let n = w.len();
        let (a, b) = (&a[..n], &b[..n]);
        let (mut r1, mut r2, mut mag) = (0.0, 0.0, 0.0);
        // Entry idx of the kernels weighs pixel xi + r − idx.
        for idx in 0..n {
            let v = f64::from(w[n - 1 - idx].to_f32());
            r1 += v * a[idx];
            r2 += v * b[idx];
            mag += (v * b[idx]).abs();
        }
        Some(finish(r1, r2, mag, xi, step))
    }
}

/// The pixel and sub-pixel step of the evaluation point nearest to `x`.
#[inline]
fn grid_point(x: f64) -> (f64, usize) {
    let xi = round(x);
    let step =
        round((x - xi + 0.5) * SUBPIXEL_STEPS as f64).clamp(0.0, SUBPIXEL_STEPS as f64) as usize;
    (xi, step)
}

/// The derivatives' sums made a result: the evaluation point, and the second derivative NaN unless a bright line
/// makes it clearly negative (not rounding noise on a flat line).
#[inline]
fn finish(r1: f64, r2: f64, mag: f64, xi: f64, step: usize) -> (f64, f64, f64) {
    let at = xi + step as f64 / SUBPIXEL_STEPS as f64 - 0.5;
    let r2 = if r2 < -1e-9 * mag.max(1e-300) {
        r2
    } else {
        f64::NAN
    };
    (r1, r2, at)
}

/// `x.round()` (half away from zero) for the finite positions and scales of this module, |x| < 2^52, without the
/// library call `round` is on the baseline x86-64 target (a tenth of a Steger frame's time): truncation and the
/// exact remainder. NaN gives 0 (its callers pass finite values only).
#[inline]
fn round(x: f64) -> f64 {
    let i = x as i64;
    let f = x - i as f64;
    (if f >= 0.5 {
        i + 1
    } else if f <= -0.5 {
        i - 1
    } else {
        i
    }) as f64
}

/// A cache of kernels by rounded scale.
#[derive(Debug, Clone, Default)]
pub struct KernelCache {
    by_step: Vec<Option<Kernels>>,
}

impl KernelCache {
    /// The kernels for scale `s` (rounded to [`SCALE_STEP`], clamped to [`MIN_SCALE`]..[`MAX_SCALE`]).
    pub fn get(&mut self, s: f64) -> &Kernels {
        let s = if s.is_finite() {
            s.clamp(MIN_SCALE, MAX_SCALE)
        } else {
            MIN_SCALE
        };
        let step = round(s / SCALE_STEP) as usize;
        if self.by_step.len() <= step {
            self.by_step.resize(step + 1, None);
        }
        self.by_step[step].get_or_insert_with(|| Kernels::new(step as f64 * SCALE_STEP))
    }
}

/// Scale for a stripe whose intensity-weighted standard deviation across the line is `sigma` pixels: a bar of
/// half-width w has sigma = w/sqrt(3), so Steger's condition s >= w/sqrt(3) asks for s >= sigma; the stripe's own
/// sigma also suppresses noise best without merging neighbours.
pub fn scale_for_width(sigma: f64) -> f64 {
    if sigma.is_finite() {
        sigma.clamp(MIN_SCALE, MAX_SCALE)
    } else {
        MIN_SCALE
    }
}

/// Farthest a 1-D Steger centre may lie from the pixel it starts at, pixels, unless the caller allows more: the
/// brightest pixel of a stripe narrower than the kernel lies within a pixel and a half of its centre.
pub const MIN_REACH_PX: f64 = 1.5;

/// 1-D Steger at integer position `x0` of a line accessed by `f(i)` (clamped at the ends): the sub-pixel position
/// where the smoothed first derivative vanishes within [`MIN_REACH_PX`] of `x0`, or `None` when the line is not
/// bright there.
pub fn steger_1d(f: impl Fn(isize) -> f64, x0: isize, k: &Kernels) -> Option<f64> {
    newton(x0, MIN_REACH_PX, |x| k.derivatives(&f, x))
}

/// [`steger_1d`] on a line of pixels, clamped at its ends, with the centre allowed up to `reach` pixels from `x0`
/// (at least [`MIN_REACH_PX`]): where the kernel's window lies inside the line (every point but those within its
/// reach of the ends) the pixels are read straight from it, without a clamp and a call per pixel (the same values,
/// so the same result to the bit).
pub fn steger_1d_line<T: Pixel>(line: &[T], x0: usize, reach: f64, k: &Kernels) -> Option<f64> {
    let last = line.len().checked_sub(1)? as isize;
    let f = |i: isize| f64::from(line[i.clamp(0, last) as usize].to_f32());
    newton(x0 as isize, reach.max(MIN_REACH_PX), |x| {
        let (xi, step) = grid_point(x);
        k.derivatives_inside(line, xi, step)
            .unwrap_or_else(|| k.derivatives(&f, x))
    })
}

/// Newton's method on the smoothed first derivative from `x0`, `derivatives(x)` giving the first and second
/// derivative at the evaluation point nearest to x and that point; the zero is kept within `reach` of `x0`.
#[inline]
fn newton(x0: isize, reach: f64, derivatives: impl Fn(f64) -> (f64, f64, f64)) -> Option<f64> {
    // Evaluated at sub-pixel positions with tabulated kernels, so the result is the zero of the derivative itself
    // (Steger's Taylor step at the pixel centre alone leaves a bias of up to delta^3 / sigma^2).
    let mut x = x0 as f64;
    for _ in 0..6 {
        let (r1, r2, at) = derivatives(x);
        if !r2.is_finite() {
            return None;
        }
        let t = -r1 / r2;
        if !t.is_finite() || t.abs() > 3.0 {
            return None;
        }
        x = at + t;
        if t.abs() < 0.5 / SUBPIXEL_STEPS as f64 {
            return ((x - x0 as f64).abs() <= reach).then_some(x);
        }
    }
    ((x - x0 as f64).abs() <= reach).then_some(x)
}

/// 2-D Steger near pixel (`u0`, `v0`) of an image accessed by `f(u, v)` (u along the scan line, v across lines):
/// returns the sub-pixel u where the detected line crosses scan line `v0`.
pub fn steger_2d(
    f: impl Fn(isize, isize) -> f64,
    u0: isize,
    v0: isize,
    k: &Kernels,
) -> Option<f64> {
    let r = k.radius as isize;
    let (mut u, mut v) = (u0, v0);
    let mut visited = [(isize::MIN, isize::MIN); 4];
    for it in 0..4 {
        visited[it] = (u, v);
        let (mut ru, mut rv, mut ruu, mut ruv, mut rvv) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for jv in -r..=r {
            let (w0v, w1v, w2v) = (
                k.d0[(jv + r) as usize],
                k.d1[(jv + r) as usize],
                k.d2[(jv + r) as usize],
            );
            for ju in -r..=r {
                let val = f(u - ju, v - jv);
                let (w0u, w1u, w2u) = (
                    k.d0[(ju + r) as usize],
                    k.d1[(ju + r) as usize],
                    k.d2[(ju + r) as usize],
                );
                ru += val * w1u * w0v;
                rv += val * w0u * w1v;
                ruu += val * w2u * w0v;
                ruv += val * w1u * w1v;
                rvv += val * w0u * w2v;
            }
        }
        // Eigenvector of the Hessian for the eigenvalue of largest magnitude.
        let tr = ruu + rvv;
        let det = ruu * rvv - ruv * ruv;
        let disc = (0.25 * tr * tr - det).max(0.0).sqrt();
        let (l1, l2) = (0.5 * tr + disc, 0.5 * tr - disc);
        let lambda = if l1.abs() > l2.abs() { l1 } else { l2 };
        if lambda >= 0.0 {
            return None;
        }
        let (mut nu, mut nv) = if ruv.abs() > 1e-12 {
            (ruv, lambda - ruu)
        } else if ruu.abs() >= rvv.abs() {
            (1.0, 0.0)
        } else {
            (0.0, 1.0)
        };
        let norm = (nu * nu + nv * nv).sqrt();
        nu /= norm;
        nv /= norm;
        let t = -(ru * nu + rv * nv) / (ruu * nu * nu + 2.0 * ruv * nu * nv + rvv * nv * nv);
        if !t.is_finite() {
            return None;
        }
        let (pu, pv) = (t * nu, t * nv);
        let next = (u + pu.round() as isize, v + pv.round() as isize);
        // Accept inside the pixel, or when the step would return to a pixel already visited (a line exactly
        // between two pixels).
        if (pu.abs() <= 0.5 && pv.abs() <= 0.5)
            || (pu.abs() <= 1.0 && pv.abs() <= 1.0 && visited.contains(&next))
        {
            // The line runs along (−nv, nu); move along it back to scan line v0.
            let (du, dv) = (-nv, nu);
            let (px, py) = (u as f64 + pu, v as f64 + pv);
            return if dv.abs() < 0.2 {
                Some(px)
            } else {
                Some(px + (v0 as f64 - py) * du / dv)
            };
        }
        (u, v) = next;
        if (v - v0).abs() > 1 {
            return None;
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reading_the_line_directly_gives_the_clamped_readings_result() {
        // Gaussian stripes at random sub-pixel centres and widths on noisy lines, some near the ends (where the
        // kernel's window leaves the line and the clamped reading takes over), in 8 and 16 bits.
        let mut rng = 99u32;
        let mut next = || {
            rng = rng.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            f64::from(rng >> 8) / f64::from(1u32 << 24)
        };
        let mut cache = KernelCache::default();
        let mut found = 0;
        for case in 0..3000 {
            let n = 40 + (next() * 80.0) as usize;
            let c = next() * (n - 1) as f64;
            let sigma = 0.6 + 3.0 * next();
            let amp = 30.0 + 200.0 * next();
            let line: Vec<f64> = (0..n)
                .map(|i| 5.0 + 4.0 * next() + amp * (-0.5 * ((i as f64 - c) / sigma).powi(2)).exp())
                .collect();
            let x0 = (c.round() as usize).min(n - 1);
            let k = cache.get(scale_for_width(sigma)).clone();
            let l8: Vec<u8> = line.iter().map(|&v| v.min(255.0) as u8).collect();
            let l16: Vec<u16> = line.iter().map(|&v| (v * 200.0) as u16).collect();
            let clamped8 = |i: isize| f64::from(l8[i.clamp(0, n as isize - 1) as usize]);
            let clamped16 = |i: isize| f64::from(l16[i.clamp(0, n as isize - 1) as usize]);
            let (a8, b8) = (
                steger_1d_line(&l8, x0, MIN_REACH_PX, &k),
                steger_1d(clamped8, x0 as isize, &k),
            );
            let (a16, b16) = (
                steger_1d_line(&l16, x0, MIN_REACH_PX, &k),
                steger_1d(clamped16, x0 as isize, &k),
            );
            assert_eq!(
                a8.map(f64::to_bits),
                b8.map(f64::to_bits),
                "u8, case {case}"
            );
            assert_eq!(
                a16.map(f64::to_bits),
                b16.map(f64::to_bits),
                "u16, case {case}"
            );
            found += usize::from(a8.is_some());
        }
        assert!(found > 2500, "{found}");
        assert_eq!(
            steger_1d_line::<u8>(&[], 0, MIN_REACH_PX, &cache.get(1.0).clone()),
            None
        );
    }

    #[test]
    fn rounding_is_the_librarys() {
        // Halves, their neighbours by an ulp, negatives, large values and zeros of both signs.
        let mut xs = vec![
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.5,
            -1.5,
            2.5,
            1e15 + 0.5,
            -1e15 - 0.5,
            4503599627370495.5,
        ];
        for k in -2000..2000 {
            let x = f64::from(k) * 0.125;
            xs.extend([
                x,
                f64::from_bits(x.to_bits() + 1),
                f64::from_bits(x.to_bits().saturating_sub(1)),
            ]);
        }
        let mut state = 0x1234_5678_u64;
        for _ in 0..10_000 {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            xs.push(((state >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 1e4);
        }
        for x in xs {
            assert_eq!(round(x), x.round(), "{x:e}");
        }
    }

    #[test]
    fn kernels_integrate_correctly() {
        let k = Kernels::new(1.5);
        assert!((k.d0.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        assert!(k.d1.iter().sum::<f64>().abs() < 1e-6);
        // The first-derivative kernel applied to a ramp gives its slope.
        let r = k.radius as isize;
        let slope: f64 = (-r..=r)
            .map(|j| (-(j as f64)) * k.d1[(j + r) as usize] * 3.0)
            .sum();
        assert!((slope - 3.0).abs() < 1e-3, "{slope}");
    }

    #[test]
    fn one_and_two_dimensional_steger_find_a_gaussian_line() {
        let c = 20.3;
        let s = 1.5;
        let line = |i: isize| 10.0 + 200.0 * (-0.5 * ((i as f64 - c) / s).powi(2)).exp();
        let mut cache = KernelCache::default();
        let k = cache.get(scale_for_width(s)).clone();
        let x = steger_1d(line, 20, &k).expect("line");
        assert!((x - c).abs() < 0.02, "{x}");
        // A slanted line in 2-D: u = c + 0.2 v.
        let img = |u: isize, v: isize| {
            10.0 + 200.0 * (-0.5 * ((u as f64 - c - 0.2 * v as f64) / s).powi(2)).exp()
        };
        let x2 = steger_2d(img, 22, 10, &k).expect("line");
        assert!((x2 - (c + 2.0)).abs() < 0.05, "{x2}");
        assert!(steger_1d(|_| 5.0, 3, &k).is_none(), "flat: no line");
    }

    #[test]
    fn a_wide_stripe_whose_brightest_pixel_speckle_moved_is_found_within_its_scale() {
        // Sigma 3 px, centre 30.3; a speckle grain makes pixel 32 the brightest, 1.7 px from the centre, and the
        // zero of the smoothed derivative lies more than MIN_REACH_PX from it.
        let c = 30.3;
        let mut line: Vec<u8> = (0..64)
            .map(|i| (100.0 * (-0.5 * ((f64::from(i) - c) / 3.0).powi(2)).exp()).round() as u8)
            .collect();
        line[32] = (f64::from(line[32]) * 1.4).round() as u8;
        assert_eq!(
            line.iter().enumerate().max_by_key(|p| p.1).map(|p| p.0),
            Some(32)
        );
        let mut cache = KernelCache::default();
        let k = cache.get(scale_for_width(3.0)).clone();
        assert_eq!(steger_1d_line(&line, 32, MIN_REACH_PX, &k), None);
        let x = steger_1d_line(&line, 32, 3.0, &k).expect("within one scale");
        assert!((x - c).abs() < 0.3, "{x}");
    }
}
