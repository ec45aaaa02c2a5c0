//! Spacetime analysis: a stripe point's position from the moment its surface point crosses the sheet, not from
//! where the stripe's light is centred in one frame (B. Curless and M. Levoy, "Better optical triangulation through
//! spacetime analysis", ICCV 1995).
//!
//! # Why
//!
//! The centre of a stripe in one frame is the centre of the light the surface sends back across the beam. Where
//! the reflectance changes inside the beam (printed texture, a dark mark), where the beam straddles a rim (part of
//! it on the top, the rest lower down), or where the surface curves under it, that centre is not where the sheet's
//! centre plane meets the surface, and triangulation puts the point off the surface: on a printed part by up to a
//! tenth of a millimetre, the size of the defects inspection looks for.
//!
//! # The method
//!
//! On a conveyor every surface point moves along x through each sheet. A point P lit by sheet `s` returns
//! `ρ(P) G(d(t))`: its own reflectance `ρ(P)`, constant, times the beam's profile at its distance `d(t)` from the
//! sheet's centre plane, which changes linearly with the travel `t`. Followed from frame to frame, P's brightness
//! is therefore a Gaussian in the travel that peaks exactly when P lies on the centre plane, whatever its
//! reflectance, its neighbours' reflectance or the surface's curvature. For a point found in frame k at pixel
//! (u, v) with label s:
//!
//! 1. its surface point P is followed through frames k−W..k+W: P in frame k+j is the triangulated point moved by
//!    the travel between the two frames, projected into the camera (its pixel moves about one column a frame), and
//!    its brightness read there (bilinear);
//! 2. the background (the darkest sample) is taken off, and a Gaussian fitted to the samples above
//!    [`MIN_SHARE`] of the brightest, contiguous around it, by Guo's weighted log-parabola ("A simple algorithm for
//!    fitting a Gaussian function", IEEE Signal Processing Magazine, 2011): `ln y = a + b t + c t²` in the travel
//!    `t`, weighted by `y²`; its peak `t* = −b / 2c` is the travel at which P is on the centre plane;
//! 3. P is the point of the ray through (u, v) in frame k that, moved by `t*`, lies on sheet s's calibrated plane.
//!
//! A temporal profile that is not a whole peak (the brightest sample at the end of the window, samples above
//! [`MIN_SHARE`] on one side of the peak only, a fit that does not open downwards) settles nothing. Where the scan's
//! first or last frames cut the window, the point keeps its frame's centre. Where the whole window lies inside the
//! scan, P was hidden part of the time or its pixel mixes the light of two surfaces (the beam straddling a rim):
//! the frame's centre is no measurement of a surface either, and the point is dropped (and counted).
//!
//! # When
//!
//! It needs several frames across the beam: the scan uses it when the frame step is at most the beam's standard
//! deviation along the travel (`laser.sigma_mm` over the cosine of the sheets' tilt; 0.30-0.42 mm for the default
//! sheets), i.e. at least 2.4 frames over the beam's full width at half maximum. The window W covers
//! [`WINDOW_SIGMAS`] of that deviation on each side. With a coarser step (the simulator's default 0.5 mm) the frame's
//! own centres are kept, with the curvature correction of [`crate::curvature`].

use crate::accumulate::Profile;
use crate::image::{Image, Pixel};
use crate::sensor::Sensor;
use crate::triangulate::FullModel;
use nalgebra::{Matrix3, Vector3};

/// Samples used in the fit are at least this share of the brightest (after the background is taken off): below it
/// the beam's tails are dominated by noise and the profile's shape by the sensor's blur.
pub const MIN_SHARE: f64 = 0.2;
/// Half width of the window followed, in standard deviations of the beam along the travel.
pub const WINDOW_SIGMAS: f64 = 3.0;
/// Most frames followed on each side of a point's own.
pub const MAX_HALF_WINDOW: usize = 16;

/// A frame the analysis can read: a grey value at any integer pixel.
pub trait Frame: Sync {
    /// Width, pixels.
    fn width(&self) -> usize;
    /// Height, pixels.
    fn height(&self) -> usize;
    /// The value at (x, y), which the caller keeps inside the frame.
    fn value(&self, x: usize, y: usize) -> f32;

    /// The value at (u, v), bilinear between the four pixels around it; `None` outside the frame.
    fn bilinear(&self, u: f64, v: f64) -> Option<f64> {
        if !(u >= 0.0 && v >= 0.0) {
            return None;
        }
        let (x, y) = (u.floor() as usize, v.floor() as usize);
        if x + 1 >= self.width() || y + 1 >= self.height() {
            return None;
        }
        let (fx, fy) = ((u - x as f64) as f32, (v - y as f64) as f32);
        let top = self.value(x, y) * (1.0 - fx) + self.value(x + 1, y) * fx;
        let bottom = self.value(x, y + 1) * (1.0 - fx) + self.value(x + 1, y + 1) * fx;
        Some(f64::from(top * (1.0 - fy) + bottom * fy))
    }
}

impl<T: Pixel> Frame for Image<T> {
    fn width(&self) -> usize {
        Image::width(self)
    }
    fn height(&self) -> usize {
        Image::height(self)
    }
    fn value(&self, x: usize, y: usize) -> f32 {
        self.data()[y * Image::width(self) + x].to_f32()
    }
}

/// What the analysis did with a scan's points.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SpacetimeStats {
    /// Points looked at.
    pub points: usize,
    /// Points placed by their peak in time.
    pub refined: usize,
    /// Points whose whole window lies inside the scan but whose brightness over it is not a whole peak (hidden
    /// part of the time, or light from two surfaces): dropped, their frame's centre being no measurement either.
    pub unsettled: usize,
}

impl SpacetimeStats {
    /// Adds another frame's counts.
    pub fn add(&mut self, other: &SpacetimeStats) {
        self.points += other.points;
        self.refined += other.refined;
        self.unsettled += other.unsettled;
    }
}

/// Spacetime analysis of a scan with a given frame step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Spacetime {
    /// Frames followed on each side of a point's own.
    pub half_window: usize,
    /// The beam's standard deviation along the travel, mm (the narrowest sheet's).
    pub sigma_travel_mm: f64,
}

impl Spacetime {
    /// The analysis for `sensor`'s sheets (its nominal `laser.sigma_mm`, the calibrated planes' tilt) at a frame step
    /// of `step_mm`; `None` when the step is too coarse for it (more than the beam's deviation along the travel).
    pub fn for_scan(sensor: &Sensor, full: &FullModel, step_mm: f64) -> Option<Self> {
        // The beam's deviation across the sheet, projected on the travel: sigma / |n_x| (n the plane's normal).
        let sigma_travel_mm = full
            .planes
            .iter()
            .map(|p| sensor.laser.sigma_mm / p.normal.x.abs().max(1e-6))
            .fold(f64::INFINITY, f64::min);
        if !(step_mm.is_finite() && step_mm > 0.0 && sigma_travel_mm.is_finite()) {
            return None;
        }
        if step_mm > sigma_travel_mm {
            return None;
        }
        let half_window =
            ((WINDOW_SIGMAS * sigma_travel_mm / step_mm).ceil() as usize).clamp(2, MAX_HALF_WINDOW);
        Some(Self {
            half_window,
            sigma_travel_mm,
        })
    }

    /// Places the points of `profile` (frame `k` of the scan) by their peaks in time; `frames` are the scan's frames
    /// in order and `travel` their travel (mm since frame 0). Points whose temporal profile is not a whole peak keep
    /// their positions.
    pub fn refine<F: Frame>(
        &self,
        profile: &mut Profile,
        frames: &[F],
        travel: &[f64],
        full: &FullModel,
    ) -> SpacetimeStats {
        let k = profile.frame;
        let mut stats = SpacetimeStats::default();
        if k >= frames.len() || k >= travel.len() {
            return stats;
        }
        let cam = &full.camera;
        let lo = k.saturating_sub(self.half_window);
        let hi = (k + self.half_window)
            .min(frames.len() - 1)
            .min(travel.len() - 1);
        let mut samples: Vec<(f64, f64)> = Vec::with_capacity(hi - lo + 1);
        // Whether the whole window lies inside the scan: a point whose crossing the scan's first or last frames cut
        // keeps its frame's centre; any other that is no whole peak is dropped.
        let whole_window =
            k >= self.half_window && k + self.half_window < frames.len().min(travel.len());
        let mut dropped: Vec<usize> = Vec::new();
        for (i, p) in profile.points.iter_mut().enumerate() {
            stats.points += 1;
            let Some(plane) = full.planes.get(usize::from(p.stripe)) else {
                continue;
            };
            // The surface point in belt coordinates at frame k.
            let at_k = Vector3::new(p.x_mm + travel[k], p.y_mm, p.z_mm);
            samples.clear();
            for (f, frame) in frames.iter().enumerate().take(hi + 1).skip(lo) {
                let t = travel[f] - travel[k];
                let moved = at_k + Vector3::new(t, 0.0, 0.0);
                // The point and its neighbours one row up and down: they cross the sheet together on a smooth
                // surface, so their sum peaks when the point does, whatever their reflectances.
                let Some(value) = cam.project(&moved).and_then(|(u, v)| {
                    Some(
                        frame.bilinear(u, v - 1.0)?
                            + frame.bilinear(u, v)?
                            + frame.bilinear(u, v + 1.0)?,
                    )
                }) else {
                    continue;
                };
                samples.push((t, value));
            }
            let Some(t_peak) = temporal_peak(&samples) else {
                if whole_window {
                    dropped.push(i);
                }
                continue;
            };
            // The point of the ray through (u, v) at frame k that, moved by t_peak, lies on the plane:
            // n·(C + λ r + t e_x) = offset.
            let (c, r) = (cam.centre(), cam.ray_direction(p.u, f64::from(p.row)));
            let denom = plane.normal.dot(&r);
            if denom.abs() < 1e-9 {
                continue;
            }
            let lambda = (plane.offset - plane.normal.dot(&c) - t_peak * plane.normal.x) / denom;
            let w = c + r * lambda;
            if !(w.x.is_finite() && w.y.is_finite() && w.z.is_finite()) {
                continue;
            }
            p.x_mm = w.x - travel[k];
            p.y_mm = w.y;
            p.z_mm = w.z;
            p.spacetime = true;
            stats.refined += 1;
        }
        stats.unsettled = dropped.len();
        if !dropped.is_empty() {
            let mut i = 0;
            profile.points.retain(|_| {
                i += 1;
                dropped.binary_search(&(i - 1)).is_err()
            });
        }
        stats
    }
}

/// The travel at which a temporal profile `(travel, brightness)` (in travel order) peaks, by Guo's weighted
/// log-parabola over the samples above [`MIN_SHARE`] of the brightest, contiguous around it; `None` when the
/// profile is not a whole peak (see the module's documentation).
pub fn temporal_peak(samples: &[(f64, f64)]) -> Option<f64> {
    if samples.len() < 3 {
        return None;
    }
    let background = samples.iter().map(|s| s.1).fold(f64::INFINITY, f64::min);
    let (imax, peak) = samples
        .iter()
        .enumerate()
        .map(|(i, s)| (i, s.1 - background))
        .fold((0, f64::NEG_INFINITY), |a, b| if b.1 > a.1 { b } else { a });
    if peak.is_nan() || peak <= 0.0 || imax == 0 || imax + 1 == samples.len() {
        return None;
    }
    let floor = MIN_SHARE * peak;
    let mut first = imax;
    while first > 0 && samples[first - 1].1 - background > floor {
        first -= 1;
    }
    let mut last = imax;
    while last + 1 < samples.len() && samples[last + 1].1 - background > floor {
        last += 1;
    }
    // The peak must fall below the floor on both sides inside the window: otherwise it is cut off.
    if first == 0 || last + 1 == samples.len() || first == imax || last == imax {
        return None;
    }
    // Weighted least squares of ln y = a + b t + c t² with weights y², t centred on the brightest sample.
    let t0 = samples[imax].0;
    let mut m = Matrix3::<f64>::zeros();
    let mut rhs = Vector3::<f64>::zeros();
    for &(t, v) in &samples[first..=last] {
        let y = v - background;
        let t = t - t0;
        let basis = Vector3::new(1.0, t, t * t);
        m += y * y * basis * basis.transpose();
        rhs += y * y * y.ln() * basis;
    }
    let coef = m.lu().solve(&rhs)?;
    let (b, c) = (coef[1], coef[2]);
    if c.is_nan() || c >= 0.0 {
        return None;
    }
    let t = -b / (2.0 * c);
    let (t_first, t_last) = (samples[first].0 - t0, samples[last].0 - t0);
    (t.is_finite() && t > t_first && t < t_last).then_some(t0 + t)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gaussian(t: f64, mu: f64, sigma: f64) -> f64 {
        (-(t - mu) * (t - mu) / (2.0 * sigma * sigma)).exp()
    }

    #[test]
    fn the_peak_in_time_ignores_the_reflectance_and_the_background() {
        for &(mu, albedo, background) in &[(0.03, 1.0, 5.0), (-0.11, 0.2, 40.0), (0.07, 3.0, 0.0)] {
            let samples: Vec<(f64, f64)> = (-8..=8)
                .map(|j| {
                    let t = 0.2 * f64::from(j);
                    (t, background + 100.0 * albedo * gaussian(t, mu, 0.35))
                })
                .collect();
            let t = temporal_peak(&samples).expect("a whole peak");
            assert!((t - mu).abs() < 1e-5, "{t} for {mu}");
        }
    }

    /// Eleven frames 0.2 mm apart of one still stripe (Gaussian, 1.6 px) at the column stripe 5 has on a 10 mm
    /// plate, dark in the frames `dark`; the profile of frame 5 with the stripe's points.
    fn still_stripe(
        dark: std::ops::Range<usize>,
    ) -> (FullModel, Vec<Image<u8>>, Vec<f64>, Profile) {
        use crate::accumulate::ProfilePoint;
        let sensor = Sensor::default();
        let model = FullModel::nominal(&sensor);
        let mut lit = Image::<u8>::new(648, 480);
        let mut points = Vec::new();
        for row in 100..380u32 {
            let c = model
                .column_at_height(5, f64::from(row), 10.0)
                .expect("in view");
            for u in (c - 6.0) as usize..=(c + 6.0) as usize {
                let d = u as f64 - c;
                lit.data_mut()[row as usize * 648 + u] = (200.0 * (-d * d / 5.12).exp()) as u8;
            }
            let w = model.point(5, c, f64::from(row)).expect("point");
            points.push(ProfilePoint {
                stripe: 5,
                row,
                u: c,
                x_mm: w.x - 1.0,
                y_mm: w.y,
                z_mm: w.z,
                intensity: 200.0,
                spacetime: false,
            });
        }
        let frames = (0..11)
            .map(|k| {
                if dark.contains(&k) {
                    Image::new(648, 480)
                } else {
                    lit.clone()
                }
            })
            .collect();
        let travel = (0..11).map(|k| 0.2 * k as f64).collect();
        let profile = Profile {
            frame: 5,
            travel_mm: 1.0,
            points,
        };
        (model, frames, travel, profile)
    }

    #[test]
    fn a_point_hidden_part_of_its_crossing_is_dropped_not_kept_at_its_frames_centre() {
        let st = Spacetime {
            half_window: 5,
            sigma_travel_mm: 0.32,
        };
        let (model, frames, travel, mut whole) = still_stripe(0..0);
        let n = whole.points.len();
        let done = st.refine(&mut whole, &frames, &travel, &model);
        assert_eq!((done.refined, done.unsettled), (n, 0), "{done:?}");
        // Placed on the plate it was triangulated on (a still stripe on a flat plate crosses where it is seen).
        assert!(
            whole
                .points
                .iter()
                .all(|p| (p.z_mm - 10.0).abs() < 0.01 && p.spacetime)
        );
        // Dark for the frames before its own: half a crossing, dropped.
        let (model, frames, travel, mut hidden) = still_stripe(0..5);
        let done = st.refine(&mut hidden, &frames, &travel, &model);
        assert_eq!((done.refined, done.unsettled), (0, n), "{done:?}");
        assert!(hidden.points.is_empty());
        // The same cut by the scan's start (a window not inside the scan): kept at its frame's centre.
        let (model, frames, travel, mut early) = still_stripe(0..0);
        early.frame = 2;
        early.travel_mm = travel[2];
        for p in &mut early.points {
            p.x_mm += 1.0 - travel[2];
        }
        let (frames, travel) = (frames[..8].to_vec(), travel[..8].to_vec());
        let done = st.refine(&mut early, &frames, &travel, &model);
        assert_eq!(done.unsettled, 0, "{done:?}");
        assert_eq!(early.points.len(), n);
    }

    #[test]
    fn a_cut_or_one_sided_profile_is_no_peak() {
        // The peak beyond the window's end.
        let rising: Vec<(f64, f64)> = (-8..=8)
            .map(|j| {
                (
                    0.2 * f64::from(j),
                    100.0 * gaussian(0.2 * f64::from(j), 1.5, 0.35),
                )
            })
            .collect();
        assert_eq!(temporal_peak(&rising), None);
        // Hidden for the first half of the crossing: samples above the floor on one side only.
        let cut: Vec<(f64, f64)> = (-8..=8)
            .map(|j| {
                let t = 0.2 * f64::from(j);
                (
                    t,
                    if t < 0.0 {
                        0.0
                    } else {
                        100.0 * gaussian(t, 0.0, 0.35)
                    },
                )
            })
            .collect();
        assert_eq!(temporal_peak(&cut), None);
        assert_eq!(temporal_peak(&[(0.0, 1.0), (0.2, 2.0)]), None);
        let flat: Vec<(f64, f64)> = (0..9).map(|j| (f64::from(j), 7.0)).collect();
        assert_eq!(temporal_peak(&flat), None);
    }
}
