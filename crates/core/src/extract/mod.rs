//! Stripe extraction: from one camera frame to the sub-pixel centre of every laser stripe on every scan line.
//!
//! The stage follows section 4 of Wu, Lee & de Silva: dominant peaks and their regions of interest on each scan
//! line ([`peaks`]), one of the sub-pixel estimators ([`subpixel`], [`steger`]), then a multi-peak policy; the
//! paper's full method ([`Method::Fuzzy`]) links peaks into stripe segments with the fuzzy single-peak detector
//! (rule base `rules/single_peak.fll`) and the gradient continuity filter.
//!
//! ```
//! use stripe3d_core::{Image, extract::{extract, ExtractParams}};
//! let mut img = Image::<u8>::new(64, 12);
//! for row in 0..12 {
//!     for (x, v) in [(30, 60u8), (31, 200), (32, 60)] {
//!         img.data_mut()[row * 64 + x] = v;
//!     }
//! }
//! let found = extract(img.view(), &ExtractParams::default()).unwrap();
//! assert_eq!(found.points.len(), 12);
//! assert!((found.points[0].x - 31.0).abs() < 1e-9);
//! ```

pub mod evidence;
pub mod lines;
pub mod peaks;
pub mod steger;
pub mod subpixel;

use crate::error::CoreError;
use crate::image::{ImageView, Pixel};
use crate::rules::RuleBase;
use evidence::{
    NoiseMap, NoiseScratch, SMOOTH_NOISE_GAIN, SumScale, smoothed, sum_scale, summed_line,
};
use lines::{FitScratch, LineParams, Node, fit_along_lines, link_lines};
use peaks::{Peak, dominant_peaks, line_noise};
use serde::{Deserialize, Serialize};
use steger::KernelCache;
use stripe3d_fuzzy::Engine;

/// One sub-pixel stripe centre on one scan line.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct StripePoint {
    /// Scan line: the image row (or column with [`Axis::Columns`]).
    pub row: u32,
    /// Sub-pixel position along the scan line (pixel centres at integers).
    pub x: f64,
    /// Peak intensity, grey levels.
    pub intensity: f32,
    /// Width of the region of interest (ROI_R − ROI_L), pixels.
    pub width: f32,
    /// Quality from 0 to 1: the peak's prominence over the frame's full scale, or for [`Method::Fuzzy`] the
    /// detector's belief that the point belongs to its stripe segment.
    pub score: f32,
    /// The profile is cut on one side ([`ExtractParams::cut_asymmetry`]): real light, but its centre may be off the
    /// sheet, and it may be a fragment of a stripe rather than a stripe.
    #[serde(default)]
    pub cut: bool,
}

/// The sub-pixel estimator.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    /// Centre of mass of the whole scan line (eq. 7): one point per line; single-stripe images only.
    Com,
    /// Centre of mass of the peak and its two neighbours (eq. 8).
    Com3,
    /// Centre of mass over the region of interest (eq. 9).
    ComRoi,
    /// Centre of mass of the pixels more than the threshold above the background (eq. 10).
    ComThreshold,
    /// Linear interpolation (eq. 11).
    Linear,
    /// Parabolic fit (eq. 12).
    Parabolic,
    /// Gaussian fit through three points (log-parabola).
    Gaussian,
    /// Blais-Rioux 4th order.
    BlaisRioux4,
    /// Blais-Rioux 8th order.
    BlaisRioux8,
    /// Steger, 1-D along the scan line.
    Steger,
    /// Steger, full 2-D Hessian.
    Steger2d,
    /// The paper's full method: dominant peaks, centre of mass over the ROI, fuzzy single-peak detector linking
    /// points into segments, gradient continuity filter.
    Fuzzy,
}

impl Method {
    /// Every method.
    pub const ALL: [Method; 12] = [
        Method::Com,
        Method::Com3,
        Method::ComRoi,
        Method::ComThreshold,
        Method::Linear,
        Method::Parabolic,
        Method::Gaussian,
        Method::BlaisRioux4,
        Method::BlaisRioux8,
        Method::Steger,
        Method::Steger2d,
        Method::Fuzzy,
    ];

    /// The command-line name.
    pub fn name(self) -> &'static str {
        match self {
            Method::Com => "com",
            Method::Com3 => "com3",
            Method::ComRoi => "com-roi",
            Method::ComThreshold => "com-threshold",
            Method::Linear => "linear",
            Method::Parabolic => "parabolic",
            Method::Gaussian => "gaussian",
            Method::BlaisRioux4 => "blais-rioux4",
            Method::BlaisRioux8 => "blais-rioux8",
            Method::Steger => "steger",
            Method::Steger2d => "steger2d",
            Method::Fuzzy => "fuzzy",
        }
    }

    /// The method called `s`.
    pub fn from_name(s: &str) -> Option<Method> {
        Method::ALL.into_iter().find(|m| m.name() == s)
    }
}

/// Direction of the scan lines.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Axis {
    /// Along image rows (stripes roughly vertical, the paper's set-up).
    #[default]
    Rows,
    /// Along image columns (stripes roughly horizontal).
    Columns,
}

/// Which of several peaks on a scan line are kept.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Policy {
    /// Every dominant peak (multi-stripe).
    #[default]
    All,
    /// The brightest peak.
    Brightest,
    /// The first along the scan line.
    First,
    /// The last along the scan line.
    Last,
    /// The peak nearest to the one kept on the previous scan line.
    Continuity,
}

/// The prominence a dominant peak needs over its bounding valleys (eq. 4).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub enum Threshold {
    /// From the local noise ([`evidence::NoiseMap`]): [`LineParams::extend_snr`] standard deviations of the noise of
    /// the tile around the peak (without line linking, [`AUTO_NOISE_FACTOR`] of them).
    #[default]
    Local,
    /// From the frame: the larger of [`AUTO_NOISE_FACTOR`] times the noise (median absolute first difference
    /// of every [`NOISE_SAMPLE_STEP`]th scan line, scaled to a standard deviation) and [`AUTO_SCALE_FRACTION`] of the brightest
    /// pixel, and at least 2 grey levels.
    Auto,
    /// From each scan line's own noise: as [`Threshold::Auto`] but with the noise of the line itself (one more
    /// pass over every line; for frames whose noise changes along the stripes, e.g. uneven ambient light).
    Line,
    /// A fixed number of grey levels.
    Fixed(f64),
}

/// The automatic threshold samples every this many scan lines for the noise (enough for a robust median at a
/// fraction of the cost of the extraction itself).
pub const NOISE_SAMPLE_STEP: usize = 24;

/// The automatic threshold for a noise level and a frame's full scale, grey levels.
fn auto_threshold(noise: f64, full: f64) -> f64 {
    (AUTO_NOISE_FACTOR * noise)
        .max(AUTO_SCALE_FRACTION * full)
        .max(2.0)
}

fn to_level(t: f64) -> u32 {
    if t.is_finite() {
        t.clamp(0.0, f64::from(u32::MAX)).round() as u32
    } else {
        u32::MAX
    }
}

/// Noise multiple of the automatic threshold. 8 sigma keeps false peaks from noise below one in 10^10 per pixel
/// while a stripe of 50 grey levels over noise of 2 stays well above it.
pub const AUTO_NOISE_FACTOR: f64 = 8.0;
/// Fraction of the brightest pixel the automatic threshold does not go below (speckle and ghost clutter scale with
/// the signal, not with the camera noise).
pub const AUTO_SCALE_FRACTION: f64 = 0.06;

/// Default of [`ExtractParams::max_asymmetry`]: off; cut stripes are marked ([`DEFAULT_CUT_ASYMMETRY`]), not
/// dropped. Dropping them at 0.4 took the demo's wrong stripe indices from 9,445 to 2,942 but made every hole look
/// larger (defect benchmark: holes' median area error 12.4%, area within 15% 98.2% -> 85.9%): where a stripe runs
/// along a hole's side, its cut points are the only measurement of the rim. Dropped, they also no longer count:
/// the demo's false points fall from 3.71% to 2.64%.
pub const DEFAULT_MAX_ASYMMETRY: f64 = f64::INFINITY;
/// Default of [`ExtractParams::cut_asymmetry`]: a profile one of whose flanks is more than 2.3 times as steep as the
/// other is marked cut. A whole Gaussian stripe of sigma >= 1 px stays below 0.3 at any sub-pixel phase; cut half a
/// sigma past its centre, a stripe of sigma >= 1.5 px is above 0.4 (unit-tested).
pub const DEFAULT_CUT_ASYMMETRY: f64 = 0.4;
/// A candidate within this many pixels of one at least [`SHOULDER_RATIO`] times as prominent on its scan line is
/// marked cut: a sheet split by an edge (a chamfer, a corner) shows as a bright peak with a dim shoulder a few
/// pixels away, and the shoulder read as a stripe of its own shifts a whole row by one index. Traced on the demo: at
/// the boss's chamfer, stripe 8 (peak 74) with a shoulder 4 px away (peak 28) shifted rows 140-186 of frame 3.
pub const SHOULDER_PX: f64 = 8.0;
/// See [`SHOULDER_PX`].
pub const SHOULDER_RATIO: f64 = 2.0;
/// Narrowest stripe (intensity-weighted sigma, pixels) whose symmetry is judged.
pub const MIN_SIGMA_FOR_SYMMETRY: f64 = 0.9;
/// Default of [`ExtractParams::width_tolerance`].
pub const DEFAULT_WIDTH_TOLERANCE: f64 = f64::INFINITY;

/// Parameters of the extraction.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ExtractParams {
    /// The sub-pixel estimator.
    pub method: Method,
    /// Peak prominence threshold: by default [`Threshold::Local`], the one every command and the simulator's
    /// in-memory chain use.
    pub threshold: Threshold,
    /// Scan line direction.
    pub axis: Axis,
    /// Multi-peak policy.
    pub policy: Policy,
    /// Largest change of a segment's gradient (pixels per scan line) the continuity filter accepts.
    pub max_gradient_change: f64,
    /// Scan lines a fuzzy segment may skip before it ends.
    pub max_gap_lines: u32,
    /// Points whose profile is more lopsided than this are dropped: |s_l − s_r| / (s_l + s_r) of the steepest
    /// one-pixel rise of the left flank and fall of the right ([`subpixel::flank_asymmetry`]). A stripe cut by an
    /// edge (the beam's tail lighting a corner, half a stripe hidden by an occluding edge) drops to the background
    /// in one pixel on the cut side, and its centre is off the sheet. Judged only on stripes at least
    /// [`MIN_SIGMA_FOR_SYMMETRY`] wide, where sampling alone cannot make a profile lopsided. Infinity keeps every
    /// point.
    pub max_asymmetry: f64,
    /// Points more lopsided than this (same measure as [`ExtractParams::max_asymmetry`]) are kept but marked
    /// [`StripePoint::cut`]: stripe coding does not let them start or vote for a stripe (the fragment a sheet's
    /// tail throws on a corner would pass for one more stripe) but labels them with the stripe they continue.
    /// Infinity marks none.
    pub cut_asymmetry: f64,
    /// Points whose stripe width differs from the frame's median width by more than this fraction are dropped
    /// (truncated or smeared profiles). Infinity keeps them.
    pub width_tolerance: f64,
    /// Half the number of neighbouring scan lines summed along the stripe before peaks are found and centres
    /// estimated ([`evidence`]): `r` sums `2r + 1` lines and raises the signal-to-noise ratio by `sqrt(2r + 1)`.
    /// 0 reads each scan line alone.
    #[serde(default = "default_along_lines")]
    pub along_lines: usize,
    /// Keep only points that make a line ([`lines`]); `None` keeps every accepted peak.
    #[serde(default = "default_line_params")]
    pub lines: Option<LineParams>,
    /// Side of the tiles the local noise is estimated in, pixels.
    #[serde(default = "default_noise_tile")]
    pub noise_tile_px: usize,
}

/// Default of [`ExtractParams::along_lines`]: three scan lines summed. Measured on the validation frames of another
/// renderer (speckle, shot and read noise): the per-line centre of a dim stripe scatters by 0.3-0.5 px, the sum of
/// three brings the median RMS from 0.18 to about 0.1 px; a wider sum blurs where a stripe bends at an edge.
pub const DEFAULT_ALONG_LINES: usize = 1;

fn default_along_lines() -> usize {
    DEFAULT_ALONG_LINES
}

fn default_line_params() -> Option<LineParams> {
    Some(LineParams::default())
}

fn default_noise_tile() -> usize {
    evidence::DEFAULT_NOISE_TILE_PX
}

impl Default for ExtractParams {
    fn default() -> Self {
        Self {
            method: Method::Steger,
            threshold: Threshold::Local,
            axis: Axis::Rows,
            policy: Policy::All,
            max_gradient_change: 2.0,
            max_gap_lines: 4,
            max_asymmetry: DEFAULT_MAX_ASYMMETRY,
            cut_asymmetry: DEFAULT_CUT_ASYMMETRY,
            width_tolerance: DEFAULT_WIDTH_TOLERANCE,
            along_lines: DEFAULT_ALONG_LINES,
            lines: default_line_params(),
            noise_tile_px: evidence::DEFAULT_NOISE_TILE_PX,
        }
    }
}

/// The stripe points of one frame.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Extraction {
    /// Points sorted by scan line, then position.
    pub points: Vec<StripePoint>,
    /// Number of scan lines.
    pub lines: u32,
    /// The threshold used, grey levels (with [`Threshold::Line`], the frame's automatic value for reference).
    pub threshold: f64,
}

impl Extraction {
    /// Scan lines on which no stripe was found.
    pub fn empty_lines(&self) -> Vec<u32> {
        let mut has = vec![false; self.lines as usize];
        for p in &self.points {
            if let Some(h) = has.get_mut(p.row as usize) {
                *h = true;
            }
        }
        has.iter()
            .enumerate()
            .filter(|(_, h)| !**h)
            .map(|(i, _)| i as u32)
            .collect()
    }
}

/// A reusable extractor: buffers, kernels and the fuzzy engine persist across frames, so extraction allocates
/// nothing per frame after the first.
#[derive(Debug, Clone)]
pub struct Extractor {
    params: ExtractParams,
    peaks: Vec<Peak>,
    hist: Vec<u32>,
    kernels: KernelCache,
    candidates: Vec<Candidate>,
    widths: Vec<f64>,
    engine: Option<Engine>,
    segments: Vec<Segment>,
    pairs: Vec<(f64, usize, usize)>,
    noise: NoiseMap,
    noise_bufs: NoiseScratch,
    sum_acc: Vec<u32>,
    sum_line: Vec<u16>,
    detect_line: Vec<u16>,
    nodes: Vec<Node>,
    keep: Vec<bool>,
    line_of: Vec<u32>,
    fit_scratch: FitScratch,
}

#[derive(Debug, Clone, Copy)]
struct Candidate {
    point: StripePoint,
    prominence: f64,
    /// Prominence over the local noise.
    snr: f64,
    segment: usize,
    /// Intensity-weighted standard deviation across the line, pixels.
    sigma: f64,
    /// Lopsidedness of the profile's flanks (see [`ExtractParams::max_asymmetry`]).
    asymmetry: f64,
}

#[derive(Debug, Clone)]
struct Segment {
    last_x: f64,
    last_line: u32,
    last_prominence: f64,
    gradient: f64,
    length: usize,
    open: bool,
}

/// Extracts with a one-off [`Extractor`].
pub fn extract<T: Pixel>(
    image: ImageView<'_, T>,
    params: &ExtractParams,
) -> Result<Extraction, CoreError> {
    let mut e = Extractor::new(params.clone())?;
    let mut out = Extraction::default();
    e.extract_into(image, &mut out);
    Ok(out)
}

impl Extractor {
    /// An extractor; fails only when the fuzzy rule base does not load.
    pub fn new(params: ExtractParams) -> Result<Self, CoreError> {
        let engine = match params.method {
            Method::Fuzzy => {
                Some(
                    RuleBase::SinglePeak
                        .engine()
                        .map_err(|e| CoreError::RuleBase {
                            file: RuleBase::SinglePeak.file_name(),
                            message: e.to_string(),
                        })?,
                )
            }
            _ => None,
        };
        Ok(Self {
            params,
            peaks: Vec::new(),
            hist: Vec::new(),
            kernels: KernelCache::default(),
            candidates: Vec::new(),
            widths: Vec::new(),
            engine,
            segments: Vec::new(),
            pairs: Vec::new(),
            noise: NoiseMap::default(),
            noise_bufs: Default::default(),
            sum_acc: Vec::new(),
            sum_line: Vec::new(),
            detect_line: Vec::new(),
            nodes: Vec::new(),
            keep: Vec::new(),
            line_of: Vec::new(),
            fit_scratch: FitScratch::default(),
        })
    }

    /// The parameters.
    pub fn params(&self) -> &ExtractParams {
        &self.params
    }

    fn line_count<T: Pixel>(&self, img: &ImageView<'_, T>) -> usize {
        match self.params.axis {
            Axis::Rows => img.height(),
            Axis::Columns => img.width(),
        }
    }

    /// The noise multiple a candidate needs with [`Threshold::Local`].
    fn extend_snr(&self) -> f64 {
        self.params
            .lines
            .map_or(AUTO_NOISE_FACTOR, |l| l.extend_snr)
    }

    /// The threshold (of the detection signal) and the frame's full scale (brightest sampled value of the summed
    /// signal).
    fn frame_threshold<T: Pixel>(&mut self, img: &ImageView<'_, T>, scale: SumScale) -> (f64, f64) {
        let lines = self.line_count(img);
        let rows_axis = self.params.axis == Axis::Rows;
        let mut noises = Vec::new();
        let mut brightest = 0u32;
        for k in (0..lines).step_by(NOISE_SAMPLE_STEP) {
            summed_line(
                img,
                rows_axis,
                k,
                scale,
                &mut self.sum_acc,
                &mut self.sum_line,
            );
            brightest = brightest.max(self.sum_line.iter().copied().max().map_or(0, u32::from));
            noises.push(SMOOTH_NOISE_GAIN * line_noise(&self.sum_line, &mut self.hist));
        }
        noises.sort_by(f64::total_cmp);
        let noise = noises.get(noises.len() / 2).copied().unwrap_or(0.0);
        let full = f64::from(brightest.max(1));
        let t = match self.params.threshold {
            Threshold::Fixed(t) => t * scale.detect_gain(),
            Threshold::Auto | Threshold::Line | Threshold::Local => {
                auto_threshold(noise, full * f64::from(evidence::SMOOTH_GAIN))
            }
        };
        (t, full)
    }

    /// The threshold for scan line `k` (of the signal `line`): the frame's, the line's own, or the local noise's
    /// smallest multiple on the line (each candidate is then held to its own tile's).
    fn line_threshold<T: Pixel>(&mut self, line: &[T], k: usize, frame: u32, full: f64) -> u32 {
        match self.params.threshold {
            Threshold::Local => to_level(self.extend_snr() * self.noise.line_min(k)).max(1),
            Threshold::Line => to_level(auto_threshold(
                SMOOTH_NOISE_GAIN * line_noise(line, &mut self.hist),
                full * f64::from(evidence::SMOOTH_GAIN),
            )),
            Threshold::Auto | Threshold::Fixed(_) => frame,
        }
    }

    /// Extracts the stripe points of `img` into `out` (replacing its contents).
    pub fn extract_into<T: Pixel>(&mut self, img: ImageView<'_, T>, out: &mut Extraction) {
        out.points.clear();
        self.candidates.clear();
        let lines = self.line_count(&img);
        out.lines = lines as u32;
        let rows_axis = self.params.axis == Axis::Rows;
        let n = 2 * self.params.along_lines + 1;
        let top = u32::from(T::MAX_VALUE);
        let max = if u64::from(top) * n as u64 <= u64::from(u16::MAX) {
            top
        } else {
            (0..img.height())
                .map(|y| img.row(y).iter().map(|p| p.to_u32()).max().unwrap_or(0))
                .max()
                .unwrap_or(0)
        };
        let scale = sum_scale(n, max);
        let local = self.params.threshold == Threshold::Local;
        let noise_known = local || self.params.lines.is_some();
        if noise_known {
            let tile = self.params.noise_tile_px;
            self.noise
                .estimate(&img, rows_axis, scale, tile, &mut self.noise_bufs);
        }
        let (t, full) = self.frame_threshold(&img, scale);
        out.threshold = if local {
            self.extend_snr() * self.noise.median() / scale.detect_gain()
        } else {
            t / scale.detect_gain()
        };
        let thr = to_level(t);
        for k in 0..lines {
            summed_line(
                &img,
                rows_axis,
                k,
                scale,
                &mut self.sum_acc,
                &mut self.sum_line,
            );
            let (line, mut detect) = (
                std::mem::take(&mut self.sum_line),
                std::mem::take(&mut self.detect_line),
            );
            smoothed(&line, &mut detect);
            let thr = self.line_threshold(&line, k, thr, full);
            self.scan_line(&detect, &line, k, thr, full, scale, noise_known, &img);
            (self.sum_line, self.detect_line) = (line, detect);
        }
        self.shape_filter();
        self.mark_shoulders();
        if let Some(lp) = self.params.lines {
            self.nodes.clear();
            self.nodes.extend(self.candidates.iter().map(|c| Node {
                line: c.point.row,
                x: c.point.x,
                snr: c.snr,
            }));
            link_lines(&self.nodes, &lp, &mut self.keep, &mut self.line_of);
            fit_along_lines(
                &mut self.nodes,
                &self.keep,
                &self.line_of,
                lp.fit_half_lines,
                &mut self.fit_scratch,
            );
            for (c, n) in self.candidates.iter_mut().zip(&self.nodes) {
                c.point.x = n.x;
            }
            let mut i = 0;
            let keep = &self.keep;
            self.candidates.retain(|_| {
                i += 1;
                keep[i - 1]
            });
        }
        if self.params.method == Method::Fuzzy {
            self.link_segments(full, out);
            return;
        }
        let mut prev_x: Option<f64> = None;
        let mut start = 0;
        let cands = &self.candidates;
        while start < cands.len() {
            let (_, end) = line_span(cands, start);
            match apply_policy(self.params.policy, &cands[start..end], &mut prev_x) {
                Kept::All => out.points.extend(cands[start..end].iter().map(|c| c.point)),
                Kept::One(i) => out.points.push(cands[start + i].point),
                Kept::None => {}
            }
            start = end;
        }
    }

    /// Marks as cut a dim candidate beside a much brighter one on its scan line ([`SHOULDER_PX`]).
    fn mark_shoulders(&mut self) {
        if !self.params.cut_asymmetry.is_finite() || self.params.method == Method::Com {
            return;
        }
        let mut start = 0;
        while start < self.candidates.len() {
            let (_, end) = line_span(&self.candidates, start);
            // Candidates of a line are in column order: only the neighbours within reach are looked at.
            for a in start..end {
                let (xa, pa) = (self.candidates[a].point.x, self.candidates[a].prominence);
                let brighter = |c: &Candidate| c.prominence >= SHOULDER_RATIO * pa;
                let near = |c: &&Candidate| (c.point.x - xa).abs() <= SHOULDER_PX;
                let cands = &self.candidates;
                let shoulder = cands[start..a].iter().rev().take_while(near).any(brighter)
                    || cands[a + 1..end].iter().take_while(near).any(brighter);
                if shoulder {
                    self.candidates[a].point.cut = true;
                }
            }
            start = end;
        }
    }

    /// Drops candidates whose profile is lopsided or whose width is far from the frame's median width.
    fn shape_filter(&mut self) {
        let enabled =
            self.params.width_tolerance.is_finite() || self.params.max_asymmetry.is_finite();
        if self.params.method == Method::Com || !enabled {
            return;
        }
        self.widths.clear();
        self.widths.extend(self.candidates.iter().map(|c| c.sigma));
        if self.widths.is_empty() {
            return;
        }
        let mid = self.widths.len() / 2;
        let median = *self.widths.select_nth_unstable_by(mid, f64::total_cmp).1;
        let (max_asym, tol) = (self.params.max_asymmetry, self.params.width_tolerance);
        self.candidates.retain(|c| {
            let greater = |a: f64, b: f64| a.partial_cmp(&b) == Some(std::cmp::Ordering::Greater);
            let symmetric = !greater(c.asymmetry, max_asym);
            let width_ok = !greater((c.sigma - median).abs(), tol * median);
            symmetric && width_ok
        });
    }

    /// Finds the dominant peaks of one scan line and estimates their centres into `self.candidates`.
    #[allow(clippy::too_many_arguments)]
    fn scan_line<T: Pixel, I: Pixel>(
        &mut self,
        detect: &[T],
        line: &[T],
        k: usize,
        thr: u32,
        full: f64,
        scale: SumScale,
        noise_known: bool,
        img: &ImageView<'_, I>,
    ) {
        let gain = scale.gain() as f32;
        let local_floor = (self.params.threshold == Threshold::Local).then(|| self.extend_snr());
        let mut peaks = std::mem::take(&mut self.peaks);
        dominant_peaks(detect, thr, &mut peaks);
        if peaks.is_empty() {
            self.peaks = peaks;
            return;
        }
        let row = k as u32;
        if self.params.method == Method::Com {
            // Eq. 7: one centre of mass for the whole line, above the line's minimum.
            let bg = line
                .iter()
                .map(|p| f64::from(p.to_f32()))
                .fold(f64::INFINITY, f64::min);
            if let Some(x) = subpixel::centre_of_mass(line, 0, line.len() - 1, bg) {
                let top = line.iter().map(|p| p.to_u32()).max().unwrap_or(0);
                let point = StripePoint {
                    row,
                    x,
                    intensity: top as f32 / gain,
                    width: line.len() as f32,
                    score: ((f64::from(top) - bg) / full) as f32,
                    cut: false,
                };
                self.candidates.push(Candidate {
                    point,
                    prominence: f64::from(top) - bg,
                    snr: f64::INFINITY,
                    segment: usize::MAX,
                    sigma: 0.0,
                    asymmetry: 0.0,
                });
            }
            self.peaks = peaks;
            return;
        }
        for d in &peaks {
            // Judged on the detection signal, against the local noise of that signal.
            let snr = if noise_known {
                let prominence = subpixel::prominence(detect, d);
                prominence / self.noise.at(d.center() as f64, k).max(f64::MIN_POSITIVE)
            } else {
                f64::INFINITY
            };
            if local_floor.is_some_and(|f| snr < f) {
                continue;
            }
            let p = &on_estimation_line(line, d);
            let bg = subpixel::background(line, p);
            let x = match self.params.method {
                Method::Com3 => subpixel::com3(line, p, bg),
                Method::ComRoi | Method::Fuzzy => {
                    subpixel::centre_of_mass(line, p.roi_left, p.roi_right, bg)
                }
                Method::ComThreshold => subpixel::centre_of_mass_threshold(
                    line,
                    p,
                    bg,
                    f64::from(thr) / f64::from(evidence::SMOOTH_GAIN),
                ),
                Method::Linear => subpixel::linear(line, p, bg),
                Method::Parabolic => subpixel::parabolic(line, p, bg),
                Method::Gaussian => subpixel::gaussian(line, p, bg),
                Method::BlaisRioux4 => subpixel::blais_rioux(line, p, 2),
                Method::BlaisRioux8 => subpixel::blais_rioux(line, p, 4),
                Method::Steger | Method::Steger2d => {
                    let s = steger::scale_for_width(stripe_sigma(line, p, bg));
                    if self.params.method == Method::Steger {
                        // Speckle moves a whole stripe's brightest pixel by up to its width, and the zero of the
                        // smoothed derivative lies within one scale (the stripe's sigma) of it. A cut profile's
                        // centre is off the sheet anyway, and a zero far from its brightest pixel is the smoothed
                        // plateau beside the cut (a sheet's tail on a lit corner), not a stripe.
                        let whole = subpixel::flank_asymmetry(line, p) <= self.params.cut_asymmetry;
                        let reach = if whole { s } else { steger::MIN_REACH_PX };
                        steger::steger_1d_line(line, p.center(), reach, self.kernels.get(s))
                    } else {
                        let axis = self.params.axis;
                        let (w, h) = (img.width() as isize, img.height() as isize);
                        let pix = |u: isize, v: isize| {
                            let (x, y) = match axis {
                                Axis::Rows => (u.clamp(0, w - 1), v.clamp(0, h - 1)),
                                Axis::Columns => (v.clamp(0, w - 1), u.clamp(0, h - 1)),
                            };
                            img.get(x as usize, y as usize)
                                .map_or(0.0, |q| f64::from(q.to_f32()))
                        };
                        steger::steger_2d(pix, p.center() as isize, k as isize, self.kernels.get(s))
                    }
                }
                Method::Com => None,
            };
            // An estimate outside the region of interest is not a centre of this peak.
            let Some(x) =
                x.filter(|x| x.is_finite() && *x >= p.roi_left as f64 && *x <= p.roi_right as f64)
            else {
                continue;
            };
            let prominence = f64::from(p.value) - bg;
            // The shape measures cost as much as the estimate itself: only when a filter asks for them.
            let (sigma, asymmetry) = if self.params.width_tolerance.is_finite()
                || self.params.max_asymmetry.is_finite()
            {
                let sigma = stripe_sigma(line, p, bg);
                let asymmetry = if sigma >= MIN_SIGMA_FOR_SYMMETRY {
                    subpixel::flank_asymmetry(line, p)
                } else {
                    0.0
                };
                (sigma, asymmetry)
            } else if self.params.cut_asymmetry.is_finite() {
                // Marking only: the width (for the narrow-stripe exemption) only for the few lopsided points.
                let a = subpixel::flank_asymmetry(line, p);
                if a > self.params.cut_asymmetry
                    && stripe_sigma(line, p, bg) >= MIN_SIGMA_FOR_SYMMETRY
                {
                    (0.0, a)
                } else {
                    (0.0, 0.0)
                }
            } else {
                (0.0, 0.0)
            };
            let point = StripePoint {
                row,
                x,
                intensity: p.value as f32 / gain,
                width: (p.roi_right - p.roi_left) as f32,
                score: (prominence / full).clamp(0.0, 1.0) as f32,
                cut: asymmetry > self.params.cut_asymmetry,
            };
            self.candidates.push(Candidate {
                point,
                prominence,
                snr,
                segment: usize::MAX,
                sigma,
                asymmetry,
            });
        }
        self.peaks = peaks;
    }

    /// The paper's single-peak detector: links candidates line by line into segments with the fuzzy rule base,
    /// drops very short segments (rule 4) and gradient discontinuities, and writes the kept points.
    fn link_segments(&mut self, full: f64, out: &mut Extraction) {
        let Some(engine) = self.engine.as_mut() else {
            return;
        };
        let (i_int, i_chg, i_gap, i_len) = (
            engine.input_index("intensity"),
            engine.input_index("intensity_change"),
            engine.input_index("gap"),
            engine.input_index("segment_length"),
        );
        let (o_same, o_keep) = (
            engine.output_index("same_segment"),
            engine.output_index("keep_segment"),
        );
        let (Some(i_int), Some(i_chg), Some(i_gap), Some(i_len), Some(o_same), Some(o_keep)) =
            (i_int, i_chg, i_gap, i_len, o_same, o_keep)
        else {
            return;
        };
        self.segments.clear();
        let gap_limit = 5.0;
        let cands = &mut self.candidates;
        let mut start = 0;
        while start < cands.len() {
            let (line, end) = line_span(cands, start);
            for s in self.segments.iter_mut() {
                if s.open && line > s.last_line + self.params.max_gap_lines {
                    s.open = false;
                }
            }
            // Beliefs for every (segment, candidate) pair close enough to matter, best first.
            let pairs = &mut self.pairs;
            pairs.clear();
            for (si, s) in self.segments.iter().enumerate().filter(|(_, s)| s.open) {
                let predicted = s.last_x + s.gradient * f64::from(line - s.last_line);
                for (ci, c) in cands.iter().enumerate().take(end).skip(start) {
                    let gap = (c.point.x - predicted).abs();
                    if gap >= gap_limit {
                        continue;
                    }
                    engine.set_input(i_int, c.prominence / full);
                    engine.set_input(i_chg, (c.prominence - s.last_prominence).abs() / full);
                    engine.set_input(i_gap, gap);
                    if engine.process().is_ok() {
                        let b = engine.output_value(o_same);
                        if b > 0.5 {
                            pairs.push((b, si, ci));
                        }
                    }
                }
            }
            pairs.sort_by(|a, b| b.0.total_cmp(&a.0));
            for &(b, si, ci) in pairs.iter() {
                if cands[ci].segment != usize::MAX || self.segments[si].last_line == line {
                    continue;
                }
                let s = &mut self.segments[si];
                let c = &mut cands[ci];
                let dl = f64::from(line - s.last_line).max(1.0);
                let g = (c.point.x - s.last_x) / dl;
                // Gradient continuity: a jump in the gradient is a discontinuity, not this segment.
                if s.length >= 2 && (g - s.gradient).abs() > self.params.max_gradient_change {
                    continue;
                }
                s.gradient = if s.length >= 2 {
                    0.5 * (s.gradient + g)
                } else {
                    g
                };
                s.last_x = c.point.x;
                s.last_line = line;
                s.last_prominence = c.prominence;
                s.length += 1;
                c.segment = si;
                c.point.score = b as f32;
            }
            for c in cands[start..end]
                .iter_mut()
                .filter(|c| c.segment == usize::MAX)
            {
                c.segment = self.segments.len();
                c.point.score = 1.0;
                self.segments.push(Segment {
                    last_x: c.point.x,
                    last_line: line,
                    last_prominence: c.prominence,
                    gradient: 0.0,
                    length: 1,
                    open: true,
                });
            }
            start = end;
        }
        // Rule 4: very short segments are ignored.
        let mut keep = vec![false; self.segments.len()];
        for (si, s) in self.segments.iter().enumerate() {
            engine.set_input(i_len, s.length as f64);
            if engine.process().is_ok() {
                keep[si] = engine.output_value(o_keep) > 0.5;
            }
        }
        out.points.extend(
            cands
                .iter()
                .filter(|c| keep.get(c.segment).copied().unwrap_or(false))
                .map(|c| c.point),
        );
        out.points
            .sort_by(|a, b| a.row.cmp(&b.row).then(a.x.total_cmp(&b.x)));
    }
}

/// A peak found on the detection signal, moved to the estimation line: its top is the brightest pixel of the line
/// within one pixel of the detected top (with the plateau of equal pixels around it), its region of interest the
/// detected one less the pixel the smoothing added on each side.
fn on_estimation_line<T: Pixel>(line: &[T], d: &Peak) -> Peak {
    let n = line.len();
    let (lo, hi) = (d.top_start.saturating_sub(1), (d.top_end + 1).min(n - 1));
    let mut c = lo;
    for i in lo..=hi {
        if line[i] > line[c] {
            c = i;
        }
    }
    let v = line[c];
    let (mut a, mut b) = (c, c);
    while a > d.roi_left && line[a - 1] == v {
        a -= 1;
    }
    while b < d.roi_right.min(n - 1) && line[b + 1] == v {
        b += 1;
    }
    Peak {
        top_start: a,
        top_end: b,
        value: v.to_u32(),
        // The kernel [1, 2, 1] spreads the detection signal by a pixel each side: the region of interest on the
        // estimation line is a pixel narrower.
        roi_left: (d.roi_left + 1).min(a),
        roi_right: d.roi_right.saturating_sub(1).max(b),
    }
}

/// Intensity-weighted standard deviation of the stripe across the scan line, within the region of interest,
/// background subtracted (1 when the region holds no signal).
fn stripe_sigma<T: Pixel>(line: &[T], p: &Peak, bg: f64) -> f64 {
    let hi = p.roi_right.min(line.len() - 1);
    let bgi = bg as u32;
    if f64::from(bgi) == bg
        && line.len() <= 1 << 16
        && hi.saturating_sub(p.roi_left) < 1 << 14
        && p.roi_left <= hi
    {
        // The usual case, an integer background: the sums in integers (no overflow: 16-bit weights, positions
        // below 2^16, fewer than 2^14 terms), without a conversion per pixel. Below 2^53 every partial sum of the
        // floating-point loop is an exact integer too, so the result is the same to the bit; above, that loop.
        let (mut s0, mut s1, mut s2) = (0u64, 0u64, 0u64);
        for (i, q) in line[p.roi_left..=hi].iter().enumerate() {
            let w = u64::from(q.to_u32().saturating_sub(bgi));
            let x = (p.roi_left + i) as u64;
            s0 += w;
            s1 += w * x;
            s2 += w * x * x;
        }
        if s2 < 1 << 53 {
            if s0 == 0 {
                return 1.0;
            }
            let (s0, s1, s2) = (s0 as f64, s1 as f64, s2 as f64);
            let m = s1 / s0;
            return (s2 / s0 - m * m).max(0.0).sqrt();
        }
    }
    let (mut s0, mut s1, mut s2) = (0.0, 0.0, 0.0);
    for (i, q) in line.iter().enumerate().take(hi + 1).skip(p.roi_left) {
        let w = (f64::from(q.to_f32()) - bg).max(0.0);
        let x = i as f64;
        s0 += w;
        s1 += w * x;
        s2 += w * x * x;
    }
    if s0 <= 0.0 {
        return 1.0;
    }
    let m = s1 / s0;
    (s2 / s0 - m * m).max(0.0).sqrt()
}

/// The scan line of `cands[start]` and the end of its run of candidates (candidates are in scan-line order).
fn line_span(cands: &[Candidate], start: usize) -> (u32, usize) {
    let line = cands[start].point.row;
    (
        line,
        start
            + cands[start..]
                .iter()
                .take_while(|c| c.point.row == line)
                .count(),
    )
}

enum Kept {
    All,
    One(usize),
    None,
}

fn apply_policy(policy: Policy, c: &[Candidate], prev_x: &mut Option<f64>) -> Kept {
    if c.is_empty() {
        return Kept::None;
    }
    let brightest = || {
        c.iter()
            .enumerate()
            .max_by(|a, b| a.1.point.intensity.total_cmp(&b.1.point.intensity))
            .map_or(0, |(i, _)| i)
    };
    let k = match policy {
        Policy::All => return Kept::All,
        Policy::Brightest => brightest(),
        Policy::First => 0,
        Policy::Last => c.len() - 1,
        Policy::Continuity => match *prev_x {
            Some(px) => c
                .iter()
                .enumerate()
                .min_by(|a, b| {
                    (a.1.point.x - px)
                        .abs()
                        .total_cmp(&(b.1.point.x - px).abs())
                })
                .map_or(0, |(i, _)| i),
            None => brightest(),
        },
    };
    *prev_x = Some(c[k].point.x);
    Kept::One(k)
}

#[cfg(test)]
mod tests;
