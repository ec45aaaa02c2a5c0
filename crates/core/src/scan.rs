//! Scanning: one frame to one triangulated profile (extract → code → triangulate); a scan's coded frames
//! reconciled across frames and triangulated ([`profiles_of`]); and the whole rest of a scan after coding —
//! reconciliation, triangulation, spacetime analysis, accumulation with the curvature correction — in
//! [`finish_scan`], what `stripe3d scan` and the simulator's in-memory pipeline both run. The command line, the
//! benchmarks and the ground-truth tests all go through [`Scanner`] and [`finish_scan`], so they measure the same
//! chain.

use crate::CoreError;
use crate::accumulate::{ModelKind, Profile, RangeGrid, RangeImage, RangeParams, profile_into};
use crate::calibrate::Calibration;
use crate::code::{
    CodedFrame, Coding, CodingParams, CodingStats, StripeCoder, TemporalParams, reconcile,
};
use crate::curvature::{CurvatureBias, correct};
use crate::extract::{ExtractParams, Extraction, Extractor};
use crate::image::{ImageView, Pixel};
use crate::sensor::Sensor;
use crate::spacetime::{Frame, Spacetime, SpacetimeStats};
use crate::triangulate::FullModel;
use rayon::prelude::*;

/// The per-frame stages of a scan with their reusable buffers. One per thread; clone it to get another.
#[derive(Debug, Clone)]
pub struct Scanner {
    extractor: Extractor,
    coder: StripeCoder,
    model: ModelKind,
    extraction: Extraction,
    coding: Coding,
}

impl Scanner {
    /// A scanner for frames of the calibrated camera; `coding` bounds the heights stripe coding allows.
    pub fn new(
        cal: &Calibration,
        extract: ExtractParams,
        coding: CodingParams,
        model: ModelKind,
    ) -> Result<Self, CoreError> {
        let cam = &cal.full.camera;
        Ok(Self {
            extractor: Extractor::new(extract)?,
            coder: StripeCoder::new(&cal.full, cam.width, cam.height, coding)?,
            model,
            extraction: Extraction::default(),
            coding: Coding::default(),
        })
    }

    /// Extracts, codes and triangulates one frame into `out`; returns the frame's coding counts.
    ///
    /// `travel_mm` is the conveyor travel since frame 0. The frame must have the calibrated camera's size (the
    /// caller checks, so that its error can name the file).
    pub fn profile_into<T: Pixel>(
        &mut self,
        frame: ImageView<'_, T>,
        index: usize,
        travel_mm: f64,
        cal: &Calibration,
        out: &mut Profile,
    ) -> CodingStats {
        self.extractor.extract_into(frame, &mut self.extraction);
        self.coder
            .code_into(&self.extraction.points, &mut self.coding);
        profile_into(
            index,
            travel_mm,
            &self.extraction.points,
            &self.coding,
            &cal.full,
            Some(&cal.linear),
            self.model,
            out,
        );
        self.coding.stats
    }

    /// Extracts and codes one frame into `out` (for [`profiles_of`], which reconciles the coding across frames).
    pub fn code_into<T: Pixel>(&mut self, frame: ImageView<'_, T>, out: &mut CodedFrame) {
        self.extractor.extract_into(frame, &mut self.extraction);
        self.coder
            .code_into(&self.extraction.points, &mut out.coding);
        out.points.clear();
        out.points.extend_from_slice(&self.extraction.points);
    }

    /// Extracts and codes one frame into `coded` and triangulates it into `out` as it is coded (before any
    /// reconciliation across frames: the line's view of a frame the moment it arrives); returns its coding counts.
    pub fn code_and_profile_into<T: Pixel>(
        &mut self,
        frame: ImageView<'_, T>,
        index: usize,
        travel_mm: f64,
        cal: &Calibration,
        coded: &mut CodedFrame,
        out: &mut Profile,
    ) -> CodingStats {
        self.code_into(frame, coded);
        profile_into(
            index,
            travel_mm,
            &coded.points,
            &coded.coding,
            &cal.full,
            Some(&cal.linear),
            self.model,
            out,
        );
        coded.coding.stats
    }

    /// The model this scanner triangulates with.
    pub fn model(&self) -> ModelKind {
        self.model
    }
}

/// A scan's coded frames (in travel order, `travel_mm[k]` for frame k) reconciled across frames (see
/// [`reconcile`]) and triangulated into profiles; returns the profiles, the coding counts after reconciliation
/// and the number of points reconciliation recovered.
pub fn profiles_of(
    frames: &mut [CodedFrame],
    travel_mm: &[f64],
    cal: &Calibration,
    model: ModelKind,
) -> (Vec<Profile>, CodingStats, usize) {
    let recovered = reconcile(frames, &TemporalParams::default());
    let mut stats = CodingStats::default();
    for f in frames.iter() {
        stats.add(&f.coding.stats);
    }
    // Frames triangulated in parallel (each on its own: the same profiles in the same order).
    let profiles = frames
        .par_iter()
        .enumerate()
        .map(|(k, f)| {
            let mut p = Profile::default();
            profile_into(
                k,
                travel_mm.get(k).copied().unwrap_or(0.0),
                &f.points,
                &f.coding,
                &cal.full,
                Some(&cal.linear),
                model,
                &mut p,
            );
            p
        })
        .collect();
    (profiles, stats, recovered)
}

/// How a scan is finished after coding.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScanOptions {
    /// Range image cell size (x, y), mm.
    pub grid_mm: [f64; 2],
    /// Correct the heights for the curvature bias of the sheets (for Steger's estimator; see [`crate::curvature`]).
    pub curvature_correction: bool,
    /// Place points by their peak in time where the frame step allows it (see [`crate::spacetime`]).
    pub spacetime: bool,
}

/// What a scan produced.
#[derive(Debug, Clone)]
pub struct ScanResult {
    /// Triangulated profiles, in frame order.
    pub profiles: Vec<Profile>,
    /// The range image.
    pub range: RangeImage,
    /// Coding counts over the scan, after reconciliation.
    pub coding: CodingStats,
    /// Points whose heights were corrected for the sheets' curvature bias.
    pub curvature_corrected: usize,
    /// The spacetime analysis the scan used (`None`: the frame step is too coarse, or it was turned off), and what
    /// it did.
    pub spacetime: Option<(Spacetime, SpacetimeStats)>,
    /// What about the input makes the result doubtful (see [`ScanWarning`]).
    pub warnings: Vec<ScanWarning>,
}

/// Largest share of a scan's stripe points that no calibrated stripe explains (outside every stripe's band over the
/// measuring range, or declared false) before the scan warns ([`ScanWarning::Unexplained`]): where the calibration
/// fits, those are extraction's few false points (a few percent); a quarter of the light or more lying where no
/// calibrated sheet can put it says the calibration does not fit the frames.
pub const MAX_UNEXPLAINED_SHARE: f64 = 0.25;

/// Something about a scan's input that makes its result doubtful, reported with the result (a scan that cannot be
/// made at all is an error instead).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ScanWarning {
    /// The scan has one frame: the range image is a single profile, with nothing across the travel.
    #[error(
        "one frame: the range image is a single profile; a scan needs frames taken while the part moves under \
         the sheets"
    )]
    OneFrame,
    /// More than [`MAX_UNEXPLAINED_SHARE`] of the stripe points lie where no calibrated stripe explains them.
    #[error(
        "{unexplained} of {points} stripe points ({:.0}%) lie where no calibrated stripe can put them: is the \
         calibration this sensor's, and the camera and lasers unmoved since?",
        100.0 * *unexplained as f64 / (*points).max(1) as f64
    )]
    Unexplained {
        /// Points no stripe explains.
        unexplained: usize,
        /// Stripe points extracted.
        points: usize,
    },
}

/// The warnings a scan of `frames` frames with coding counts `coding` earns.
pub fn scan_warnings(frames: usize, coding: &CodingStats) -> Vec<ScanWarning> {
    let mut out = Vec::new();
    if frames == 1 {
        out.push(ScanWarning::OneFrame);
    }
    if coding.noise as f64 > MAX_UNEXPLAINED_SHARE * coding.points as f64 {
        out.push(ScanWarning::Unexplained {
            unexplained: coding.noise,
            points: coding.points,
        });
    }
    out
}

/// The spacetime analysis a scan of `sensor` with travel `travel` (mm, per frame) uses, if any: the caller keeps
/// the frames for [`finish_scan`] when this is `Some`.
pub fn spacetime_for(
    sensor: &Sensor,
    cal: &Calibration,
    travel: &[f64],
    options: &ScanOptions,
) -> Option<Spacetime> {
    if !options.spacetime {
        return None;
    }
    Spacetime::for_scan(sensor, &cal.full, travel_step(travel)?)
}

/// The typical conveyor travel between frames (the median step), mm; `None` with fewer than two frames.
pub fn travel_step(travel: &[f64]) -> Option<f64> {
    let mut steps: Vec<f64> = travel.windows(2).map(|w| w[1] - w[0]).collect();
    if steps.is_empty() {
        return None;
    }
    steps.sort_by(f64::total_cmp);
    Some(steps[steps.len() / 2])
}

/// Finishes a scan from its coded frames (in travel order, `travel[k]` for frame k): reconciles them across frames,
/// triangulates, places points in time when [`spacetime_for`] says so (`frames` are then the scan's frames, all of
/// them, in order; otherwise they may be empty) and accumulates them onto a range image with the curvature
/// correction. `method` is the extraction's estimator (the curvature model is made for Steger's).
#[allow(clippy::too_many_arguments)]
pub fn finish_scan<F: Frame>(
    coded: &mut [CodedFrame],
    frames: &[F],
    travel: &[f64],
    sensor: &Sensor,
    cal: &Calibration,
    model: ModelKind,
    method: crate::extract::Method,
    options: &ScanOptions,
) -> Result<ScanResult, CoreError> {
    let (mut profiles, coding, _) = profiles_of(coded, travel, cal, model);
    if profiles.iter().all(|p| p.points.is_empty()) {
        return Err(CoreError::NothingMeasured {
            frames: coded.len(),
            points: coding.points,
        });
    }
    let spacetime = spacetime_for(sensor, cal, travel, options)
        .filter(|_| frames.len() == coded.len())
        .map(|st| {
            let done = refine_in_time(&mut profiles, frames, travel, &cal.full, &st);
            (st, done)
        });
    let bias = options
        .curvature_correction
        .then(|| CurvatureBias::new(sensor, &cal.full, method))
        .flatten();
    let (range, curvature_corrected) =
        range_image_corrected(&mut profiles, options.grid_mm, bias.as_ref())?;
    Ok(ScanResult {
        warnings: scan_warnings(coded.len(), &coding),
        profiles,
        range,
        coding,
        curvature_corrected,
        spacetime,
    })
}

/// Places every point of a scan's profiles by its peak in time where its temporal profile is a whole peak (see
/// [`crate::spacetime`]); `frames` and `travel` are the scan's, in order. Frames in parallel.
pub fn refine_in_time<F: Frame>(
    profiles: &mut [Profile],
    frames: &[F],
    travel: &[f64],
    full: &FullModel,
    spacetime: &Spacetime,
) -> SpacetimeStats {
    profiles
        .par_iter_mut()
        .map(|p| spacetime.refine(p, frames, travel, full))
        .reduce(SpacetimeStats::default, |mut a, b| {
            a.add(&b);
            a
        })
}

/// The range image of a scan's profiles (in frame order) on a grid of `spacing_mm`: samples of one stripe and row
/// in consecutive frames are joined when they are at most 2.5 frame steps apart (so a grid finer than the travel
/// per frame has no empty columns), and never across a height step.
pub fn range_image(profiles: &[Profile], spacing_mm: [f64; 2]) -> Result<RangeImage, CoreError> {
    let mut grid = RangeGrid::covering(profiles, range_params(profiles, spacing_mm))?;
    grid.accumulate(profiles);
    Ok(grid.image())
}

/// The grid [`range_image`] accumulates a scan on.
fn range_params(profiles: &[Profile], spacing_mm: [f64; 2]) -> RangeParams {
    let step = profiles
        .windows(2)
        .map(|w| (w[1].travel_mm - w[0].travel_mm).abs())
        .fold(0.0f64, f64::max);
    RangeParams {
        spacing_mm,
        max_fill_mm: (2.5 * step).max(spacing_mm[0] * 1.5),
        ..RangeParams::default()
    }
}

/// [`range_image`], with the profiles' heights corrected for the curvature bias of the sheets first when `bias` is
/// given (see [`crate::curvature`]: the range image is built, its derivatives estimated, every point corrected
/// where the model holds, and the range image built again); returns the range image and the number of points
/// corrected.
pub fn range_image_corrected(
    profiles: &mut [Profile],
    spacing_mm: [f64; 2],
    bias: Option<&CurvatureBias>,
) -> Result<(RangeImage, usize), CoreError> {
    match bias {
        None => Ok((range_image(profiles, spacing_mm)?, 0)),
        Some(bias) => {
            let params = range_params(profiles, spacing_mm);
            correct(profiles, bias, params)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_scan_warns_of_one_frame_and_of_light_no_calibrated_stripe_explains() {
        let counts = |points, noise| CodingStats {
            points,
            coded: points - noise,
            ambiguous: 0,
            noise,
        };
        assert!(
            scan_warnings(22, &counts(1000, 250)).is_empty(),
            "a quarter is allowed"
        );
        assert_eq!(
            scan_warnings(22, &counts(1000, 251)),
            [ScanWarning::Unexplained {
                unexplained: 251,
                points: 1000
            }]
        );
        let one = scan_warnings(1, &counts(1000, 10));
        assert_eq!(one, [ScanWarning::OneFrame]);
        assert!(one[0].to_string().contains("single profile"));
        assert!(scan_warnings(5, &CodingStats::default()).is_empty());
    }
}
