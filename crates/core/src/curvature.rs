//! Curvature bias: where a laser sheet of finite thickness lights a curved surface, the centre of the light the
//! camera sees is not where the sheet's centre plane meets the surface, and triangulation with that plane puts the
//! point off the surface. Measured on the simulated defect plates before this correction: bumps and dents 0.03 to
//! 0.04 mm too high or too low near the ends of the view, the error growing with the curvature and changing sign
//! across the view.
//!
//! # The model
//!
//! Across a sheet of Gaussian profile (standard deviation σ, `laser.sigma_mm`), a surface point at distance `s`
//! from the centre plane is lit in proportion to `exp(−s²/2σ²)`, and a Lambertian surface sends the camera light in
//! proportion to `n·l` (surface normal, direction to the source). Along the scan line (image u, world x, the
//! direction in which `s` changes) write `t` for the surface's offset from where `s = 0`; on a surface `z = f(x, y)`:
//! - `s(t) = a t + ½ b t²` with `a = m·(1, 0, f_x)` and `b = m_z f_xx` (m the sheet's unit normal);
//! - the shading `n·l` changes by `g = d ln(n·l)/dt` per mm (for a sheet whose source lies in the sheet this is
//!   `−f_xx l_x / l_z` on a level surface);
//! - the image coordinate `u(t)` is not linear in `t` either (perspective on a sloped, curved surface).
//!
//! A profile `G(s)(1 + g t)` peaks at `s = σ² g / a` whatever the smoothing. The two non-linear mappings skew the
//! profile: with `β = (u''/u' − b/a) / a` its centroid lies at `s = 1.5 β σ²`, and a maximum of the profile smoothed
//! by a Gaussian of variance Σ² (Steger's detector) moves a share `κ = Σ² / (σ_u² + Σ²)` of that (σ_u the stripe's
//! own standard deviation in pixels; from the first and third cumulants of the skewed profile). The point found
//! lies at `s* = σ² (g/a + 1.5 κ β)` from the plane, and moving along the camera ray (unit r) onto the plane takes
//! it `e = −s* (r_z − f_x r_x − f_y r_y) / (m·r)` above the surface. With Steger's scale equal to the stripe's
//! image sigma (as extraction chooses it) and the camera's blur (`camera.psf_sigma_px`, plus the pixel's own 1/12),
//! `Σ² = σ_u² + 2 c` with `c = psf² + 1/12`.
//!
//! Checked against the simulator (profile points of defect plates, heights against the true surface): the model
//! predicts 80-90% of the error, bin by bin across the view; the extractor's κ measured on rendered skewed stripes
//! is 0.58 and 0.53 where the formula gives 0.57 and 0.54.
//!
//! # The correction
//!
//! The surface's derivatives come from the scan itself: the range image is smoothed (Gaussian, missing cells left
//! out; cells with too little measured around them get none) and differenced. The points where the uncorrected
//! range image is curved are corrected by `e` at their place, in [`PASSES`] passes, each estimating the
//! derivatives from the range image the pass before left (the bias bends the measured surface too: near the ends
//! of the view its curvature is up to twice the true one, so one pass corrects only part of it); between passes the
//! range image takes back and adds again only the tracks of the points corrected. Only where the model holds:
//! every cell of the stencil measured, slopes below 1, curvatures below 2/mm, and a correction of at most
//! [`MAX_CORRECTION_MM`] (edges and steps are left as measured). It is made for Steger's detector (the scans'
//! default); other estimators are left uncorrected.
//!
//! Cost, measured on one core: a depth image of 22 frames whose every point lies on a curved surface takes 118 ms
//! instead of 10 (`cargo bench -p stripe3d-core --bench scan`); on the flat plate of `stripe3d bench sensor`, where
//! only the points at its edges are corrected, the whole depth image from the frames takes 130 ms instead of 100.

use crate::CoreError;
use crate::accumulate::{Profile, RangeGrid, RangeImage, RangeParams};
use crate::extract::Method;
use crate::extract::steger::{MAX_SCALE, MIN_SCALE};
use crate::sensor::{Camera, Sensor};
use crate::triangulate::{FullModel, Plane};
use nalgebra::Vector3;
use rayon::prelude::*;

/// Largest height correction applied, mm: a larger prediction means the surface is not smooth at the sheet's scale
/// (an edge, a step) and the model does not hold.
pub const MAX_CORRECTION_MM: f64 = 0.1;
/// Standard deviation of the smoothing before differencing, mm (about the sheet's footprint).
const SMOOTH_MM: f64 = 0.25;
/// Half the step of the finite differences, mm.
const STEP_MM: f64 = 0.4;
/// Largest slope and curvature (1/mm) the correction trusts.
const MAX_SLOPE: f64 = 1.0;
/// Curvature (1/mm) below which a point is left as it is: the bias is about proportional to the curvature, 0.01 to
/// 0.05 mm at 0.4/mm near the ends of the paper's view, so below 6 µm here, the noise of one point; the curvature
/// of a plane measured with the default noise scatters by about 0.02/mm, so a plane is left alone.
const MIN_CURVATURE: f64 = 0.05;
const MAX_CURVATURE: f64 = 2.0;

/// The local shape of the surface at a point: first and second derivatives of the height.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Derivatives {
    /// ∂z/∂x.
    pub fx: f64,
    /// ∂z/∂y.
    pub fy: f64,
    /// ∂²z/∂x².
    pub fxx: f64,
    /// ∂²z/∂x∂y.
    pub fxy: f64,
}

/// The curvature-bias model of one sensor and calibration, for one estimator.
#[derive(Debug, Clone)]
pub struct CurvatureBias {
    camera: Camera,
    planes: Vec<Plane>,
    source: Vector3<f64>,
    sigma_mm: f64,
    /// The camera's blur plus the pixel's width, as a variance in pixels².
    blur_px2: f64,
}

impl CurvatureBias {
    /// The model for `sensor`'s laser and camera with the calibrated `full` model; `None` for estimators the model
    /// does not describe (every one but Steger's).
    pub fn new(sensor: &Sensor, full: &FullModel, method: Method) -> Option<Self> {
        if method != Method::Steger || full.planes.is_empty() {
            return None;
        }
        let sigma_mm = sensor.laser.sigma_mm;
        let psf = sensor.camera.psf_sigma_px;
        (sigma_mm.is_finite() && sigma_mm > 0.0 && psf.is_finite()).then(|| Self {
            camera: full.camera.clone(),
            planes: full.planes.clone(),
            source: sensor.laser.source(),
            sigma_mm,
            blur_px2: psf * psf + 1.0 / 12.0,
        })
    }

    /// Height error (mm, measured minus true) of the point `p` (world frame) of stripe `stripe` on a surface with
    /// derivatives `d` there; `None` where the model does not hold.
    pub fn error_mm(&self, stripe: usize, p: &Vector3<f64>, d: &Derivatives) -> Option<f64> {
        let m = self.planes.get(stripe)?.normal;
        let sigma2 = self.sigma_mm * self.sigma_mm;
        // The surface point at offset t along x, and its normal.
        let at = |t: f64| p + Vector3::new(t, 0.0, d.fx * t + 0.5 * d.fxx * t * t);
        let normal =
            |t: f64| Vector3::new(-(d.fx + d.fxx * t), -(d.fy + d.fxy * t), 1.0).normalize();
        // Direction to the source within the sheet.
        let light = |q: &Vector3<f64>| {
            let v = self.source - q;
            (v - m * m.dot(&v)).normalize()
        };
        let shading = |t: f64| normal(t).dot(&light(&at(t)));
        const H: f64 = 0.05;
        let (s_minus, s_plus) = (shading(-H), shading(H));
        if s_minus < 0.05 || s_plus < 0.05 {
            return None;
        }
        let g = (s_plus / s_minus).ln() / (2.0 * H);
        let a = m.x + m.z * d.fx;
        if a.abs() < 0.2 {
            return None;
        }
        let b = m.z * d.fxx;
        let u = |t: f64| self.camera.project(&at(t)).map(|(u, _)| u);
        let (u0, up, um) = (u(0.0)?, u(H)?, u(-H)?);
        let u1 = (up - um) / (2.0 * H);
        let u2 = (up - 2.0 * u0 + um) / (H * H);
        if u1.abs() < 1e-6 {
            return None;
        }
        let beta = (u2 / u1 - b / a) / a;
        // The stripe's own spread in pixels, Steger's scale and the blur: the share of the skew the maximum takes.
        let su2 = sigma2 * (u1 / a).powi(2);
        let scale2 = (su2 + self.blur_px2).clamp(MIN_SCALE * MIN_SCALE, MAX_SCALE * MAX_SCALE);
        let kappa = (scale2 + self.blur_px2) / (su2 + scale2 + self.blur_px2);
        let s_star = sigma2 * (g / a + 1.5 * kappa * beta);
        let r = (p - self.camera.centre()).normalize();
        let mr = m.dot(&r);
        if mr.abs() < 1e-3 {
            return None;
        }
        let e = -s_star * (r.z - d.fx * r.x - d.fy * r.y) / mr;
        e.is_finite().then_some(e)
    }
}

/// Derivative maps of a range image (smoothed, then differenced where asked); a cell whose stencil is not all
/// measured has none.
#[derive(Debug, Clone)]
pub struct DerivativeMaps {
    origin_mm: [f64; 2],
    spacing_mm: [f64; 2],
    width: usize,
    height: usize,
    /// The smoothed heights (NaN where unmeasured); empty when the range image's heights do not fill its grid.
    smooth: Vec<f64>,
    /// Half the stencil, in cells along x and y, and in mm.
    step_cells: [usize; 2],
    step_mm: [f64; 2],
}

impl DerivativeMaps {
    /// The derivatives of `range`'s heights.
    pub fn of(range: &RangeImage) -> Self {
        let [dx, dy] = range.spacing_mm;
        let smooth = smoothed(range, [SMOOTH_MM / dx, SMOOTH_MM / dy]);
        let (hx, hy) = (
            ((STEP_MM / dx).round() as usize).max(1),
            ((STEP_MM / dy).round() as usize).max(1),
        );
        let fills = smooth.len() == range.width * range.height;
        Self {
            origin_mm: range.origin_mm,
            spacing_mm: range.spacing_mm,
            width: range.width,
            height: range.height,
            smooth: if fills { smooth } else { Vec::new() },
            step_cells: [hx, hy],
            step_mm: [hx as f64 * dx, hy as f64 * dy],
        }
    }

    /// The derivatives at part coordinates (x, y), mm: those of the nearest cell.
    pub fn at(&self, x: f64, y: f64) -> Option<Derivatives> {
        // Nearest cell by truncation of the position plus one half (`round` is a library call on the baseline
        // x86-64 target); NaN fails the comparisons.
        let i = (x - self.origin_mm[0]) / self.spacing_mm[0] + 0.5;
        let j = (self.origin_mm[1] - y) / self.spacing_mm[1] + 0.5;
        if !(i >= 0.0 && j >= 0.0 && i < self.width as f64 && j < self.height as f64) {
            return None;
        }
        self.cell(i as usize, j as usize)
    }

    /// The derivatives of cell (i, j): central differences over the stencil of ± `step_cells`.
    fn cell(&self, i: usize, j: usize) -> Option<Derivatives> {
        let [hx, hy] = self.step_cells;
        let [sx, sy] = self.step_mm;
        if self.smooth.is_empty()
            || i < hx
            || j < hy
            || i + hx >= self.width
            || j + hy >= self.height
        {
            return None;
        }
        let w = self.width;
        let z = |ii: usize, jj: usize| self.smooth[jj * w + ii];
        let c = z(i, j);
        let (l, r) = (z(i - hx, j), z(i + hx, j));
        // Row j grows towards −y.
        let (up, down) = (z(i, j - hy), z(i, j + hy));
        let corners = [
            z(i + hx, j - hy),
            z(i - hx, j + hy),
            z(i + hx, j + hy),
            z(i - hx, j - hy),
        ];
        if !(c.is_finite()
            && l.is_finite()
            && r.is_finite()
            && up.is_finite()
            && down.is_finite()
            && corners.iter().all(|v| v.is_finite()))
        {
            return None;
        }
        let d = Derivatives {
            fx: (r - l) / (2.0 * sx),
            fy: (up - down) / (2.0 * sy),
            fxx: (r - 2.0 * c + l) / (sx * sx),
            fxy: ((corners[0] - corners[3]) - (corners[2] - corners[1])) / (4.0 * sx * sy),
        };
        let fine = d.fx.abs() <= MAX_SLOPE
            && d.fy.abs() <= MAX_SLOPE
            && d.fxx.abs() <= MAX_CURVATURE
            && d.fxy.abs() <= MAX_CURVATURE;
        fine.then_some(d)
    }
}

/// Share of the smoothing kernel's weight that must fall on measured cells for a smoothed height.
const MIN_COVERAGE: f64 = 0.6;

/// Heights smoothed by a Gaussian of `sigma` cells along x and y, over the measured cells only (normalised
/// convolution); NaN where less than [`MIN_COVERAGE`] of the kernel's weight falls on measured cells.
fn smoothed(range: &RangeImage, sigma: [f64; 2]) -> Vec<f64> {
    let (w, h) = (range.width, range.height);
    if w == 0 || h == 0 || range.z.len() != w * h {
        return vec![f64::NAN; range.z.len()];
    }
    let kernel = |s: f64| -> Vec<f64> {
        let r = (2.0 * s).ceil().max(1.0) as isize;
        let k: Vec<f64> = (-r..=r)
            .map(|t| (-0.5 * (t as f64 / s.max(1e-6)).powi(2)).exp())
            .collect();
        let sum: f64 = k.iter().sum();
        k.into_iter().map(|v| v / sum).collect()
    };
    // Separable passes over (weight × height, weight); cells beyond the grid weigh nothing. Each cell sums its
    // taps in the same order along both axes (the row pass adds whole rows, which the compiler vectorises).
    let along_x = |src: &[(f64, f64)], k: &[f64]| -> Vec<(f64, f64)> {
        let r = k.len() / 2;
        let mut out = vec![(0.0, 0.0); w * h];
        // Rows in parallel (each cell's sum is the same whichever thread makes it).
        src.par_chunks_exact(w)
            .zip(out.par_chunks_exact_mut(w))
            .for_each(|(row, o)| {
                for (i, cell) in o.iter_mut().enumerate() {
                    let lo = i.saturating_sub(r);
                    let hi = (i + r).min(w - 1);
                    let mut acc = (0.0, 0.0);
                    for (kv, &(vz, vw)) in k[lo + r - i..].iter().zip(&row[lo..=hi]) {
                        acc.0 += kv * vz;
                        acc.1 += kv * vw;
                    }
                    *cell = acc;
                }
            });
        out
    };
    let along_y = |src: &[(f64, f64)], k: &[f64]| -> Vec<(f64, f64)> {
        let r = k.len() / 2;
        let mut out = vec![(0.0, 0.0); w * h];
        out.par_chunks_exact_mut(w).enumerate().for_each(|(j, o)| {
            let lo = j.saturating_sub(r);
            let hi = (j + r).min(h - 1);
            for (kv, jj) in k[lo + r - j..].iter().zip(lo..=hi) {
                for (cell, &(vz, vw)) in o.iter_mut().zip(&src[jj * w..(jj + 1) * w]) {
                    cell.0 += kv * vz;
                    cell.1 += kv * vw;
                }
            }
        });
        out
    };
    let z: Vec<(f64, f64)> = range
        .z
        .iter()
        .map(|&v| {
            if v.is_finite() {
                (f64::from(v), 1.0)
            } else {
                (0.0, 0.0)
            }
        })
        .collect();
    let once = along_x(&z, &kernel(sigma[0]));
    along_y(&once, &kernel(sigma[1]))
        .into_iter()
        .zip(&range.z)
        .map(|((vz, vw), &raw)| {
            if raw.is_finite() && vw >= MIN_COVERAGE {
                vz / vw
            } else {
                f64::NAN
            }
        })
        .collect()
}

/// Passes of the correction: the surface the derivatives come from is the one corrected by the pass before (the
/// bias sharpens one flank of a bump and softens the other, so derivatives of the measured surface alone over- and
/// under-predict it).
pub const PASSES: usize = 3;

/// Corrects the heights of `profiles` for the curvature bias and returns their range image on a grid of `params`
/// (as [`RangeGrid::accumulate`] makes it) and the number of points corrected. The points where the uncorrected
/// range image is curved (at least `MIN_CURVATURE` along x or across) are corrected, each pass estimating the
/// surface's derivatives from the latest range image and setting every such point to its measured height less the
/// bias predicted there (points where the model does not hold keep their measured height); the range image takes
/// back only the tracks of the points that moved ([`RangeGrid::update`]).
pub fn correct(
    profiles: &mut [Profile],
    bias: &CurvatureBias,
    params: RangeParams,
) -> Result<(RangeImage, usize), CoreError> {
    let mut grid = RangeGrid::covering(profiles, params)?;
    grid.accumulate_to_update(profiles);
    let mut range = grid.image();
    // The points on curved surfaces (profile, point, measured height): the others keep their heights.
    let maps = DerivativeMaps::of(&range);
    // Every point is looked at (frames in parallel, kept in order).
    let curved: Vec<(usize, usize, f64)> = profiles
        .par_iter()
        .enumerate()
        .map(|(i, profile)| {
            profile
                .points
                .iter()
                .enumerate()
                .filter(|(_, q)| {
                    !q.spacetime
                        && maps.at(q.x_mm, q.y_mm).is_some_and(|d| {
                            d.fxx.abs() >= MIN_CURVATURE || d.fxy.abs() >= MIN_CURVATURE
                        })
                })
                .map(|(j, q)| (i, j, q.z_mm))
                .collect::<Vec<_>>()
        })
        .flatten()
        .collect();
    if curved.is_empty() {
        return Ok((range, 0));
    }
    let mut maps = Some(maps);
    let mut n = 0;
    for _ in 0..PASSES {
        let maps = match maps.take() {
            Some(m) => m,
            None => DerivativeMaps::of(&range),
        };
        n = 0;
        for &(i, j, z) in &curved {
            let travel = profiles[i].travel_mm;
            let q = &mut profiles[i].points[j];
            q.z_mm = z;
            let Some(d) = maps.at(q.x_mm, q.y_mm) else {
                continue;
            };
            let world = Vector3::new(q.x_mm + travel, q.y_mm, z);
            match bias.error_mm(usize::from(q.stripe), &world, &d) {
                Some(e) if e.abs() <= MAX_CORRECTION_MM => {
                    q.z_mm = z - e;
                    n += 1;
                }
                _ => {}
            }
        }
        grid.update(profiles, curved.iter().map(|&(i, j, _)| (i, j)));
        range = grid.image();
        if n == 0 {
            break;
        }
    }
    Ok((range, n))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accumulate::ProfilePoint;

    fn model() -> CurvatureBias {
        let sensor = Sensor::default();
        CurvatureBias::new(&sensor, &FullModel::nominal(&sensor), Method::Steger)
            .expect("steger is modelled")
    }

    /// A range image of `f` on a 0.1 mm grid over ±`half` mm.
    fn surface(half: f64, f: impl Fn(f64, f64) -> f64) -> RangeImage {
        let n = (2.0 * half / 0.1).round() as usize + 1;
        let mut z = Vec::with_capacity(n * n);
        for j in 0..n {
            for i in 0..n {
                let (x, y) = (-half + i as f64 * 0.1, half - j as f64 * 0.1);
                z.push(f(x, y) as f32);
            }
        }
        RangeImage {
            origin_mm: [-half, half],
            spacing_mm: [0.1, 0.1],
            width: n,
            height: n,
            z,
            intensity: None,
        }
    }

    #[test]
    fn only_stegers_detector_is_modelled() {
        let sensor = Sensor::default();
        let full = FullModel::nominal(&sensor);
        assert!(CurvatureBias::new(&sensor, &full, Method::Steger).is_some());
        assert!(CurvatureBias::new(&sensor, &full, Method::Gaussian).is_none());
    }

    #[test]
    fn a_level_plane_has_no_bias_and_curvature_has_one_that_turns_with_it() {
        let m = model();
        let p = Vector3::new(30.0, 5.0, 10.0);
        // Stripe 9 of the default sensor crosses z = 10 near x = 30.
        let stripe = (0..11)
            .min_by(|&a, &b| {
                let d = |s: usize| m.planes[s].distance(&p).abs();
                d(a).total_cmp(&d(b))
            })
            .expect("stripes");
        let level = m
            .error_mm(stripe, &p, &Derivatives::default())
            .expect("level");
        assert!(level.abs() < 2e-4, "level plane: {level}");
        let bump = Derivatives {
            fxx: -0.5,
            ..Derivatives::default()
        };
        let dent = Derivatives {
            fxx: 0.5,
            ..Derivatives::default()
        };
        let up = m.error_mm(stripe, &p, &bump).expect("bump");
        let down = m.error_mm(stripe, &p, &dent).expect("dent");
        // What the simulator shows at the far +x end of the view: a bump's top reads high, a dent's bottom low, by
        // one to a few hundredths of a millimetre.
        assert!(up > 0.005 && up < 0.05, "bump top error {up}");
        assert!((up + down).abs() < 0.1 * up, "{up} vs {down}");
        // Halving the curvature halves the error (first order).
        let half = m
            .error_mm(
                stripe,
                &p,
                &Derivatives {
                    fxx: -0.25,
                    ..Derivatives::default()
                },
            )
            .expect("half");
        assert!((half / up - 0.5).abs() < 0.1, "{half} vs {up}");
    }

    /// The error of Steger's detector on a curved surface found the long way: the camera's row rendered from the
    /// sheet's Gaussian, Lambertian shading and the camera's blur (ray by ray, 32 samples a pixel), the stripe
    /// found as extraction finds it, and the point triangulated with the sheet's plane.
    fn rendered_error(m: &CurvatureBias, stripe: usize, fx: f64, fxx: f64) -> f64 {
        use crate::extract::steger::{Kernels, scale_for_width, steger_1d};
        let (y, z0) = (5.0, 10.0);
        let plane = m.planes[stripe];
        let x0 = (plane.offset - plane.normal.y * y - plane.normal.z * z0) / plane.normal.x;
        let surf = |x: f64| z0 + fx * (x - x0) + 0.5 * fxx * (x - x0).powi(2);
        let slope = |x: f64| fx + fxx * (x - x0);
        let cam = &m.camera;
        let (u0, v0) = cam.project(&Vector3::new(x0, y, z0)).expect("in view");
        let (uc, fine, half) = (u0.round(), 32i64, 30i64);
        let radiance: Vec<f64> = (-(half + 3) * fine..=(half + 3) * fine)
            .map(|i| {
                let d = cam.ray_direction(uc + i as f64 / fine as f64, v0);
                let c = cam.centre();
                let mut lam = cam.height_mm - z0;
                for _ in 0..20 {
                    let p = c + d * lam;
                    lam -= (p.z - surf(p.x)) / (d.z - slope(p.x) * d.x);
                }
                let p = c + d * lam;
                let n = Vector3::new(-slope(p.x), 0.0, 1.0).normalize();
                let l = (m.source - p).normalize();
                let s = plane.distance(&p);
                (-0.5 * (s / m.sigma_mm).powi(2)).exp() * n.dot(&l).max(0.0)
            })
            .collect();
        let psf = (m.blur_px2 - 1.0 / 12.0).sqrt();
        let reach = (4.0 * psf * fine as f64) as i64;
        let kernel: Vec<f64> = (-reach..=reach)
            .map(|t| (-0.5 * (t as f64 / fine as f64 / psf).powi(2)).exp())
            .collect();
        let ksum: f64 = kernel.iter().sum();
        let centre = (half + 3) * fine;
        let pixels: Vec<f64> = (-half..=half)
            .map(|px| {
                let mut acc = 0.0;
                for t in -fine / 2..fine / 2 {
                    let at = centre + px * fine + t;
                    for (q, kv) in kernel.iter().enumerate() {
                        acc += kv * radiance[(at + q as i64 - reach) as usize];
                    }
                }
                acc / ksum / fine as f64
            })
            .collect();
        let top = (0..pixels.len())
            .max_by(|&a, &b| pixels[a].total_cmp(&pixels[b]))
            .expect("pixels");
        let (mut s0, mut s1, mut s2) = (0.0, 0.0, 0.0);
        for (i, v) in pixels.iter().enumerate() {
            if (i as i64 - top as i64).abs() <= 8 {
                let x = i as f64;
                s0 += v;
                s1 += v * x;
                s2 += v * x * x;
            }
        }
        let sd = (s2 / s0 - (s1 / s0).powi(2)).sqrt();
        let k = Kernels::new(scale_for_width(sd));
        let found = steger_1d(
            |i| pixels[i.clamp(0, pixels.len() as isize - 1) as usize],
            top as isize,
            &k,
        )
        .expect("a stripe");
        let u = uc + found - half as f64;
        let full = FullModel {
            camera: m.camera.clone(),
            planes: m.planes.clone(),
        };
        let q = full.point(stripe, u, v0).expect("on the plane");
        q.z - surf(q.x)
    }

    #[test]
    fn the_model_predicts_what_a_rendered_stripe_shows() {
        let m = model();
        for stripe in [1, 5, 10] {
            for fx in [-0.2, 0.0, 0.2] {
                // What the rendering and the detector do on a level surface (a few µm) is not the curvature's.
                let level = rendered_error(&m, stripe, fx, 0.0);
                for fxx in [-0.4, 0.4] {
                    let rendered = rendered_error(&m, stripe, fx, fxx) - level;
                    let plane = m.planes[stripe];
                    let x0 = (plane.offset - plane.normal.y * 5.0 - plane.normal.z * 10.0)
                        / plane.normal.x;
                    let d = Derivatives {
                        fx,
                        fxx,
                        ..Derivatives::default()
                    };
                    let model = m
                        .error_mm(stripe, &Vector3::new(x0, 5.0, 10.0), &d)
                        .expect("modelled");
                    assert!(
                        (model - rendered).abs() <= 0.3 * rendered.abs() + 0.003,
                        "stripe {stripe}, f_x {fx}, f_xx {fxx}: rendered {rendered:.4} mm, model {model:.4} mm"
                    );
                }
            }
        }
    }

    #[test]
    fn derivative_maps_are_exact_on_a_quadratic_and_absent_at_steps_and_holes() {
        let f =
            |x: f64, y: f64| 5.0 + 0.1 * x - 0.05 * y + 0.15 * x * x + 0.05 * x * y - 0.1 * y * y;
        let maps = DerivativeMaps::of(&surface(3.0, f));
        let d = maps.at(0.5, -0.4).expect("inside");
        assert!(
            (d.fx - (0.1 + 0.3 * 0.5 + 0.05 * -0.4)).abs() < 1e-3,
            "{d:?}"
        );
        assert!(
            (d.fy - (-0.05 + 0.05 * 0.5 - 0.2 * -0.4)).abs() < 1e-3,
            "{d:?}"
        );
        assert!((d.fxx - 0.3).abs() < 1e-3, "{d:?}");
        assert!((d.fxy - 0.05).abs() < 1e-3, "{d:?}");
        // Near the grid's border the stencil is incomplete.
        assert!(maps.at(2.9, 0.0).is_none());
        // A 1 mm step: no derivatives next to it, nor next to a missing cell.
        let mut step = surface(3.0, |x, _| if x < 0.0 { 5.0 } else { 6.0 });
        let maps = DerivativeMaps::of(&step);
        assert!(maps.at(0.1, 0.0).is_none());
        assert!(maps.at(-2.0, 0.0).is_some());
        let k = 30 * step.width + 10; // x = -2.0, y = 0
        step.z[k] = f32::NAN;
        let maps = DerivativeMaps::of(&step);
        assert!(maps.at(-2.0, 0.0).is_none());
        assert!(maps.at(-2.0, 1.5).is_some());
    }

    #[test]
    fn correcting_points_biased_as_the_model_says_gives_the_surface_back() {
        // A 0.4 mm bell of radius 2 mm at x = 30 (the far end of the view), sampled by the nearest stripe every
        // 0.1 mm, its heights off by what the model predicts from the true surface; the correction estimates the
        // surface from the biased range image and must take most of the error away.
        let m = model();
        let (cx, amp, r0) = (30.0, 0.4, 2.0);
        let f = |x: f64, y: f64| {
            let d = (x - cx).hypot(y);
            10.0 + if d < r0 {
                amp * 0.5 * (1.0 + (std::f64::consts::PI * d / r0).cos())
            } else {
                0.0
            }
        };
        let truth = |x: f64, y: f64| {
            let h = 1e-3;
            Derivatives {
                fx: (f(x + h, y) - f(x - h, y)) / (2.0 * h),
                fy: (f(x, y + h) - f(x, y - h)) / (2.0 * h),
                fxx: (f(x + h, y) - 2.0 * f(x, y) + f(x - h, y)) / (h * h),
                fxy: (f(x + h, y + h) - f(x + h, y - h) - f(x - h, y + h) + f(x - h, y - h))
                    / (4.0 * h * h),
            }
        };
        let stripe = 9;
        let mut profile = Profile::default();
        let mut worst_before: f64 = 0.0;
        let (mut ss_before, mut count) = (0.0, 0usize);
        // Points every 0.1 mm over an 8 mm square about the bell.
        for j in 0..=80 {
            for i in 0..=80 {
                let (x, y) = (cx - 4.0 + i as f64 * 0.1, 4.0 - j as f64 * 0.1);
                let z = f(x, y);
                let e = m
                    .error_mm(stripe, &Vector3::new(x, y, z), &truth(x, y))
                    .unwrap_or(0.0);
                worst_before = worst_before.max(e.abs());
                if (x - cx).abs() < 2.4 && y.abs() < 2.4 {
                    ss_before += e * e;
                    count += 1;
                }
                profile.points.push(ProfilePoint {
                    stripe: stripe as u16,
                    row: 0,
                    u: 0.0,
                    x_mm: x,
                    y_mm: y,
                    z_mm: z + e,
                    intensity: 100.0,
                    spacetime: false,
                });
            }
        }
        assert!(worst_before > 0.01, "the bell's bias is {worst_before} mm");
        let mut profiles = vec![profile];
        // One frame: every point lands in its own cell of a 0.1 mm grid, nothing is filled between them.
        let params = RangeParams {
            spacing_mm: [0.1, 0.1],
            ..RangeParams::default()
        };
        let (range, n) = correct(&mut profiles, &m, params).expect("a grid");
        let (x, y) = (cx + 0.6, 0.0);
        let z = f64::from(range.at(x, y).expect("measured"));
        assert!(
            (z - f(x, y)).abs() < 0.02,
            "range image at the flank {z} against {}",
            f(x, y)
        );
        assert!(n > 1000, "{n} points corrected");
        let ss_after: f64 = profiles[0]
            .points
            .iter()
            .filter(|q| (q.x_mm - cx).abs() < 2.4 && q.y_mm.abs() < 2.4)
            .map(|q| (q.z_mm - f(q.x_mm, q.y_mm)).powi(2))
            .sum();
        let (before, after) = (
            (ss_before / count as f64).sqrt(),
            (ss_after / count as f64).sqrt(),
        );
        assert!(before > 0.005, "RMS bias {before} mm");
        assert!(after < 0.35 * before, "RMS error {before} -> {after} mm");
    }
}
