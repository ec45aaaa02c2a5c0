//! Defect detection: regions of the characterization maps that deviate, gaps in the data, and material missing
//! from the part's outline, classified by the paper's surface rules (`rules/surface.fll`, through the fuzzy engine)
//! and measured.
//!
//! 1. **The part** is the largest 8-connected set of cells above the belt; specks elsewhere are not the part.
//! 2. **Deviating regions**: seeds where the 3 x 3 smoothed deviation exceeds [`DetectParams::seed_mm`] (not within
//!    [`DetectParams::edge_band_mm`] of the part's edge, where half-lit stripes bias heights), grown over cells of
//!    the same sign above [`DetectParams::grow_mm`] (hysteresis).
//! 3. **Gaps**: regions without part data enclosed by the part, where the reference expects surface.
//! 4. **Edge chips**: cells inside the expected outline (the convex hull of the part, cut to where the reference
//!    expects surface) that are not the part and are open to the outside.
//! 5. Each candidate's evidence (largest |mean curvature|, direction uniformity, gap size, height similarity across
//!    the gap, elongation, notch depth) goes through the rule base; the most certain output names the kind, its
//!    certainty is the confidence; below 0.5 the kind is `anomaly`.
//! 6. **Measurement**: bumps and dents are fitted with a smooth bell (raised cosine, least squares with an offset,
//!    Levenberg-Marquardt), which gives the footprint (area), centre and height free of the detection threshold; the
//!    volume sums the measured deviation over the footprint. Holes, chips and scratches are measured from their
//!    cells; a hole's depth is down to the belt when its bottom is not seen (the part lies on the belt).

use crate::CoreError;
use crate::accumulate::RangeImage;
use crate::characterize::{
    CellClass, CharacterizeParams, PreparedGolden, ReferenceInfo, ReferenceSource, SurfaceMaps,
    cell_xy, geometry_at, median, reference_heights, remove_outliers, surface_maps,
};
use crate::rules::RuleBase;
use stripe3d_fuzzy::Engine;

/// The kinds of defect.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum DefectKind {
    /// Material raised above the surface, smooth.
    Bump,
    /// Material pressed below the surface, smooth.
    Dent,
    /// A gap in the surface with similar heights around it.
    Hole,
    /// A long, narrow groove.
    Scratch,
    /// Material missing from the part's outline.
    EdgeChip,
    /// A deviation the rules could not name with certainty.
    Anomaly,
}

impl DefectKind {
    /// Every kind.
    pub const ALL: [DefectKind; 6] = [
        DefectKind::Bump,
        DefectKind::Dent,
        DefectKind::Hole,
        DefectKind::Scratch,
        DefectKind::EdgeChip,
        DefectKind::Anomaly,
    ];

    /// The name in reports: `bump`, `dent`, `hole`, `scratch`, `edge-chip`, `anomaly`.
    pub fn name(self) -> &'static str {
        match self {
            DefectKind::Bump => "bump",
            DefectKind::Dent => "dent",
            DefectKind::Hole => "hole",
            DefectKind::Scratch => "scratch",
            DefectKind::EdgeChip => "edge-chip",
            DefectKind::Anomaly => "anomaly",
        }
    }

    /// The kind of a report name.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.name() == name)
    }
}

/// What the rules were told about a candidate.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Evidence {
    /// Largest |mean curvature| in the region, 1/mm.
    pub curvature_per_mm: f64,
    /// Signed uniformity of the deviation: −1 all downward, +1 all upward.
    pub direction: f64,
    /// Equivalent diameter of a gap in the data, mm (0 for surface regions).
    pub gap_mm: f64,
    /// Height difference between the two sides of a gap, mm.
    pub height_similarity_mm: f64,
    /// Length over width (1 for round).
    pub elongation: f64,
    /// How far missing material reaches into the outline, mm.
    pub edge_notch_mm: f64,
    /// Cells of the region.
    pub cells: usize,
}

/// One defect, located and measured (part coordinates).
#[derive(Debug, Clone, PartialEq)]
pub struct Defect {
    /// What it is.
    pub kind: DefectKind,
    /// Centre, mm.
    pub centroid_mm: [f64; 2],
    /// Bounding box x0, y0, x1, y1, mm.
    pub bbox_mm: [f64; 4],
    /// Footprint area, mm².
    pub area_mm2: f64,
    /// Greatest height (bump) or depth (the others) relative to the reference, mm.
    pub depth_mm: f64,
    /// Material added or removed, mm³.
    pub volume_mm3: f64,
    /// Certainty of the kind, 0 to 1 (the rule base's output).
    pub confidence: f64,
    /// Whether a hole's bottom was seen (false: assumed through to the belt).
    pub bottom_seen: bool,
    /// The evidence the rules weighed.
    pub evidence: Evidence,
}

/// A region the scan could not measure and that is not a hole (a shadow, an occlusion): reported so that "no
/// defect" never silently covers unmeasured surface.
#[derive(Debug, Clone, PartialEq)]
pub struct Unmeasured {
    /// Centre, mm.
    pub centroid_mm: [f64; 2],
    /// Area, mm².
    pub area_mm2: f64,
    /// Why it is not a hole.
    pub reason: String,
}

/// Parameters of detection.
#[derive(Debug, Clone, PartialEq)]
pub struct DetectParams {
    /// Smoothed deviation that starts a region, mm. Half the smallest defect of interest (0.1 mm); 20 times the
    /// smoothed height noise of the default set-up (about 0.0025 mm), so clean plates stay clean.
    pub seed_mm: f64,
    /// Smoothed deviation a region grows over, mm.
    pub grow_mm: f64,
    /// Smallest region reported, mm².
    pub min_area_mm2: f64,
    /// Smallest gap considered, mm² (scattered empty cells are not holes).
    pub min_gap_mm2: f64,
    /// Band along the part's edges (and the rims of holes) where regions are not seeded, mm: half-lit stripes
    /// there are biased by up to 0.4 mm, and the grid carries the bias about one frame step (0.5 mm) inward
    /// (measured at hole rims on the defect benchmark).
    pub edge_band_mm: f64,
    /// Cells this far (mm) from the median of their 5 x 5 neighbourhood are outliers (see
    /// [`crate::characterize::remove_outliers`]): a stripe coded one index off lands 1.3 mm or more away, while the
    /// mixed cells on the rim of a hole (top and wall samples averaged) stay within 1 mm and keep holes their size
    /// (0.5 mm cost 6% of the holes their 15% area tolerance on the defect benchmark).
    pub outlier_mm: f64,
    /// Anomalies (regions the rules cannot name) smaller than this are reported as unmeasured outlier heights,
    /// mm²: a wrongly coded stripe fragment gives a few cells millimetres off.
    pub min_anomaly_mm2: f64,
    /// Least share of an edge notch's cells that must show the belt for it to be missing material.
    pub min_seen_share: f64,
    /// Certainty below which a candidate is an `anomaly`.
    pub min_confidence: f64,
    /// Most candidates evaluated (a guard against a wildly wrong reference).
    pub max_candidates: usize,
    /// Smallest hole, in conveyor travel steps across (equivalent diameter of its gap), when the step is known
    /// ([`DetectParams::travel_step_mm`]): a stripe's samples missing for two or three frames (coding dropped them as
    /// ambiguous) leave a gap with the surface's height on every side, as a hole does. Measured on the demo part
    /// scanned with seeds 1-7 against its golden scan: such gaps up to 1.55 mm (3.1 steps of 0.5 mm) across, four
    /// of which were reported as holes; the smallest holes of interest (2 mm) leave 1.93 mm or more (3.9 steps;
    /// `bench defects`). Smaller gaps are reported as unmeasured, with this reason.
    pub min_hole_travel_steps: f64,
    /// Narrowest bump or dent, in conveyor travel steps along x at half its peak deviation, when the step is known
    /// ([`DetectParams::travel_step_mm`]). One frame's samples misplaced (a stripe read 1.5-2 mm low on three rows
    /// of one frame of the demo part) deviate over about one step, the fill between the frames before and after;
    /// a raised-cosine bump or dent of diameter D is D / 2 wide there, a step per millimetre of diameter at 0.5 mm
    /// a frame. Measured: the demo part's false one-frame dent 0.22 mm wide (0.44 steps), the narrowest true bump
    /// or dent of `bench defects` (2 mm across) 0.88 mm (1.76 steps). Narrower regions are reported as unmeasured.
    pub min_region_travel_steps: f64,
    /// Conveyor travel between frames, mm (the sampling step along x), when known. The last sample before a hole
    /// lies anywhere up to a step short of its rim, and the first after it as far beyond: a hole's measured area
    /// is corrected by the expected excess on each side that ends on measured surface (`hole_area`).
    pub travel_step_mm: Option<f64>,
    /// Probability that the scan's own height noise starts a region anywhere on a clean part. The seed threshold is
    /// raised above [`DetectParams::seed_mm`] where the noise needs it (see [`Detectable`]); 0 keeps `seed_mm`
    /// whatever the noise.
    pub false_alarm: f64,
}

/// What a scan lets inspection see, from the scan's own height noise.
///
/// The noise is the robust standard deviation (1.4826 x the median absolute deviation from the median) of the
/// smoothed deviation over the part, away from its edges: defects cover a small share of a part, so they do not move
/// it. Over the part's independent samples (its cells over the 9 of the smoothing window), Gaussian noise of that
/// deviation exceeds `k` standard deviations somewhere with probability [`DetectParams::false_alarm`] when
/// `k = Φ⁻¹(1 − false_alarm / 2n)`; the seed threshold is the larger of the method's `seed_mm` and `k` times the
/// noise, and the growth threshold keeps its ratio to it.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Detectable {
    /// Robust standard deviation of the smoothed deviation over the part, mm.
    pub noise_mm: f64,
    /// Standard deviations of that noise a seed must reach (0: no noise condition).
    pub sigmas: f64,
    /// The smoothed deviation that starts a region, mm: the smallest bump height or dent depth seen.
    pub threshold_mm: f64,
    /// Whether the noise raised the threshold above the method's.
    pub raised: bool,
    /// Smallest hole seen, mm across (from the smallest gap and, when the travel step is known, the fewest steps).
    pub hole_mm: f64,
}

/// The standard normal quantile `Φ⁻¹(p)`, 0 < p < 1 (P. J. Acklam's rational approximation, relative error below
/// 1.2e-9). Written out here rather than taken from a statistics crate: it is the one function inspection needs.
pub fn normal_quantile(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969683028665376e1,
        2.209460984245205e2,
        -2.759285104469687e2,
        1.383_577_518_672_69e2,
        -3.066479806614716e1,
        2.506628277459239,
    ];
    const B: [f64; 5] = [
        -5.447609879822406e1,
        1.615858368580409e2,
        -1.556989798598866e2,
        6.680131188771972e1,
        -1.328068155288572e1,
    ];
    const C: [f64; 6] = [
        -7.784894002430293e-3,
        -3.223964580411365e-1,
        -2.400758277161838,
        -2.549732539343734,
        4.374664141464968,
        2.938163982698783,
    ];
    const D: [f64; 4] = [
        7.784695709041462e-3,
        3.224671290700398e-1,
        2.445134137142996,
        3.754408661907416,
    ];
    if p.is_nan() || p <= 0.0 {
        return f64::NEG_INFINITY;
    }
    if p >= 1.0 {
        return f64::INFINITY;
    }
    let tail = |q: f64| {
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    };
    const LOW: f64 = 0.02425;
    if p < LOW {
        tail((-2.0 * p.ln()).sqrt())
    } else if p > 1.0 - LOW {
        -tail((-2.0 * (1.0 - p).ln()).sqrt())
    } else {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    }
}

/// The [`Detectable`] of a part whose smoothed deviations (away from its edges) are `smoothed`.
fn detectable(smoothed: &mut [f64], params: &DetectParams) -> Detectable {
    let hole_mm = {
        let gap = (4.0 * params.min_gap_mm2 / std::f64::consts::PI).sqrt();
        let steps = params
            .travel_step_mm
            .map_or(0.0, |s| s * params.min_hole_travel_steps);
        gap.max(steps)
    };
    let mut out = Detectable {
        threshold_mm: params.seed_mm,
        hole_mm,
        ..Detectable::default()
    };
    if smoothed.len() < 9 || params.false_alarm <= 0.0 {
        return out;
    }
    let centre = median(smoothed);
    let mut dev: Vec<f64> = smoothed.iter().map(|v| (v - centre).abs()).collect();
    out.noise_mm = 1.4826 * median(&mut dev);
    let samples = smoothed.len() as f64 / 9.0;
    out.sigmas = normal_quantile(1.0 - params.false_alarm / (2.0 * samples.max(1.0)));
    let needed = out.sigmas * out.noise_mm;
    if needed > params.seed_mm {
        out.threshold_mm = needed;
        out.raised = true;
    }
    out
}

impl Default for DetectParams {
    fn default() -> Self {
        Self {
            seed_mm: 0.05,
            grow_mm: 0.02,
            min_area_mm2: 0.5,
            min_gap_mm2: 0.8,
            edge_band_mm: 1.0,
            outlier_mm: 1.0,
            min_anomaly_mm2: 2.0,
            min_seen_share: 0.3,
            min_confidence: 0.5,
            max_candidates: 500,
            min_hole_travel_steps: 3.5,
            min_region_travel_steps: 1.5,
            travel_step_mm: None,
            false_alarm: 0.01,
        }
    }
}

/// The surface rule base, ready to evaluate.
#[derive(Debug, Clone)]
pub struct SurfaceRules {
    engine: Engine,
    inputs: [usize; 6],
    outputs: [(usize, DefectKind); 5],
}

fn rule_error(e: impl ToString) -> CoreError {
    CoreError::RuleBase {
        file: RuleBase::Surface.file_name(),
        message: e.to_string(),
    }
}

impl SurfaceRules {
    /// The shipped rule base.
    pub fn shipped() -> Result<Self, CoreError> {
        Self::from_engine(RuleBase::Surface.engine().map_err(rule_error)?)
    }

    /// A surface engine (inputs `curvature`, `direction`, `gap`, `height_similarity`, `elongation`, `edge_notch`;
    /// outputs `bump`, `dent`, `hole`, `scratch`, `edge_chip`), e.g. one tuned from operators' feedback.
    pub fn from_engine(engine: Engine) -> Result<Self, CoreError> {
        let input = |name: &str| {
            engine
                .input_index(name)
                .ok_or_else(|| rule_error(format!("no input variable `{name}`")))
        };
        let output = |name: &str| {
            engine
                .output_index(name)
                .ok_or_else(|| rule_error(format!("no output variable `{name}`")))
        };
        let inputs = [
            input("curvature")?,
            input("direction")?,
            input("gap")?,
            input("height_similarity")?,
            input("elongation")?,
            input("edge_notch")?,
        ];
        let outputs = [
            (output("bump")?, DefectKind::Bump),
            (output("dent")?, DefectKind::Dent),
            (output("hole")?, DefectKind::Hole),
            (output("scratch")?, DefectKind::Scratch),
            (output("edge_chip")?, DefectKind::EdgeChip),
        ];
        Ok(Self {
            engine,
            inputs,
            outputs,
        })
    }

    /// The engine (for learning, which tunes its terms).
    pub fn engine(&self) -> &Engine {
        &self.engine
    }

    /// Degree to which `x` is `term` of input variable `input` (None when the rule base has no such term): what a
    /// report says about why the rules decided as they did.
    pub fn degree(&self, input: &str, term: &str, x: f64) -> Option<f64> {
        let v = &self.engine.inputs[self.engine.input_index(input)?];
        let t = v.terms.iter().find(|t| t.name == term)?;
        Some(t.shape.membership(x, &[], &[]))
    }

    /// Kind and certainty for `e`.
    pub fn classify(
        &mut self,
        e: &Evidence,
        min_confidence: f64,
    ) -> Result<(DefectKind, f64), CoreError> {
        let values = [
            e.curvature_per_mm,
            e.direction,
            e.gap_mm,
            e.height_similarity_mm,
            e.elongation,
            e.edge_notch_mm,
        ];
        for (&i, &v) in self.inputs.iter().zip(&values) {
            self.engine
                .set_input(i, if v.is_finite() { v } else { 0.0 });
        }
        self.engine.process().map_err(rule_error)?;
        let mut best = (DefectKind::Anomaly, 0.0);
        for &(o, kind) in &self.outputs {
            let v = self.engine.output_value(o);
            if v.is_finite() && v > best.1 {
                best = (kind, v);
            }
        }
        if best.1 < min_confidence {
            best.0 = DefectKind::Anomaly;
        }
        Ok(best)
    }
}

/// Where a candidate came from: which test of [`detect`] found it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum CandidateSource {
    /// A region of the surface deviating from the reference.
    Surface,
    /// An enclosed region without data.
    Gap,
    /// Missing material at the outline (the belt seen where the part should be).
    Edge,
}

impl CandidateSource {
    /// Name in reports and the history database: `surface`, `gap`, `edge`.
    pub fn name(self) -> &'static str {
        match self {
            CandidateSource::Surface => "surface",
            CandidateSource::Gap => "gap",
            CandidateSource::Edge => "edge",
        }
    }

    /// The source of a name.
    pub fn from_name(name: &str) -> Option<Self> {
        [Self::Surface, Self::Gap, Self::Edge]
            .into_iter()
            .find(|s| s.name() == name)
    }
}

/// Every region the rules weighed, reported or not: what learning from operators' feedback re-decides with tuned
/// rules (see [`decide`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Candidate {
    /// Which test found it.
    pub source: CandidateSource,
    /// Centre, mm (part coordinates).
    pub centroid_mm: [f64; 2],
    /// Area, mm².
    pub area_mm2: f64,
    /// The rules' inputs.
    pub evidence: Evidence,
    /// The rules' answer.
    pub kind: DefectKind,
    /// Its certainty.
    pub confidence: f64,
    /// Whether it became a [`Defect`].
    pub reported: bool,
    /// The index of that defect in [`Detection::defects`].
    pub defect: Option<usize>,
}

/// The decision [`detect`] takes on one candidate: its kind and certainty, and whether it is reported as a defect.
/// Surface regions are reported unless the rules cannot name them and they are smaller than
/// [`DetectParams::min_anomaly_mm2`]; gaps only as holes; edge notches only as edge chips. Learning re-runs exactly
/// this with tuned rules.
pub fn decide(
    source: CandidateSource,
    evidence: &Evidence,
    area_mm2: f64,
    rules: &mut SurfaceRules,
    params: &DetectParams,
) -> Result<(DefectKind, f64, bool), CoreError> {
    let (kind, confidence) = rules.classify(evidence, params.min_confidence)?;
    let reported = match source {
        CandidateSource::Surface => {
            !(kind == DefectKind::Anomaly && area_mm2 < params.min_anomaly_mm2)
        }
        CandidateSource::Gap => kind == DefectKind::Hole && !below_sampling(evidence, params),
        CandidateSource::Edge => kind == DefectKind::EdgeChip,
    };
    Ok((kind, confidence, reported))
}

/// A gap narrower (equivalent diameter) than [`DetectParams::min_hole_travel_steps`] conveyor travel steps, when the
/// step is known: the scan may simply have missed samples there.
fn below_sampling(evidence: &Evidence, params: &DetectParams) -> bool {
    params
        .travel_step_mm
        .is_some_and(|step| evidence.gap_mm < params.min_hole_travel_steps * step)
}

/// The region's widest extent along x (the conveyor's travel) within one row, over its cells at least half its peak
/// deviation, mm: a single frame's misplaced samples deviate over about one travel step (the fill between the
/// frames before and after), a bump or dent of diameter D over about D / 2 (a raised cosine's width at half its
/// height).
fn half_peak_travel_width(
    range: &RangeImage,
    cells: &[usize],
    deviation: &[f32],
    sign: f64,
    peak: f64,
) -> f64 {
    let w = range.width;
    let half = 0.5 * peak;
    // Cells come in row order (components are collected by a scan of the grid): one row's run at a time.
    let mut widest = 0usize;
    let mut row: Option<(usize, usize, usize)> = None;
    for &k in cells {
        if f64::from(deviation[k]) * sign < half {
            continue;
        }
        let (i, j) = (k % w, k / w);
        row = match row {
            Some((r, lo, hi)) if r == j => Some((r, lo.min(i), hi.max(i))),
            other => {
                if let Some((_, lo, hi)) = other {
                    widest = widest.max(hi - lo + 1);
                }
                Some((j, i, i))
            }
        };
    }
    if let Some((_, lo, hi)) = row {
        widest = widest.max(hi - lo + 1);
    }
    widest as f64 * range.spacing_mm[0]
}

/// Decides a candidate (see [`decide`]) and keeps it in `out.candidates`.
fn weigh(
    out: &mut Detection,
    source: CandidateSource,
    centroid_mm: [f64; 2],
    area_mm2: f64,
    evidence: Evidence,
    rules: &mut SurfaceRules,
    params: &DetectParams,
) -> Result<(DefectKind, f64, bool), CoreError> {
    let (kind, confidence, reported) = decide(source, &evidence, area_mm2, rules, params)?;
    out.candidates.push(Candidate {
        source,
        centroid_mm,
        area_mm2,
        evidence,
        kind,
        confidence,
        reported,
        defect: None,
    });
    Ok((kind, confidence, reported))
}

/// What detection found.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Detection {
    /// Defects, sorted by position (y descending, then x) for stable reports.
    pub defects: Vec<Defect>,
    /// Unmeasured regions that are not holes.
    pub unmeasured: Vec<Unmeasured>,
    /// Conditions that limit what the inspection can say (the part runs out of the view, little data).
    pub warnings: Vec<String>,
    /// Cells of the part.
    pub part_cells: usize,
    /// Share of the expected outline that holds data.
    pub coverage: f64,
    /// Bounding box of the part's measured surface x0, y0, x1, y1, mm (the product frame is centred on it).
    pub part_bbox_mm: [f64; 4],
    /// Every candidate the rules weighed, in the order found.
    pub candidates: Vec<Candidate>,
    /// What this scan let inspection see.
    pub detectable: Detectable,
}

/// Labels 4- or 8-connected components of cells where `member` holds; returns (labels, sizes); label 0 = none.
/// Components are numbered in raster order of their first cell.
///
/// Run-based two-pass labelling: the runs of member cells of each row are found once, runs that touch a run of the
/// row above are merged in a union-find, and the labels are written run by run. `member` is evaluated once per cell
/// (the breadth-first search it replaces looked at every cell up to nine times and took 5 ms on an 841 x 641 grid).
fn components(
    w: usize,
    h: usize,
    member: impl Fn(usize) -> bool,
    eight: bool,
) -> (Vec<u32>, Vec<usize>) {
    fn find(parent: &mut [usize], mut a: usize) -> usize {
        while parent[a] != a {
            parent[a] = parent[parent[a]];
            a = parent[a];
        }
        a
    }
    // Runs: (row, start, end exclusive); row_start[j] = index of the first run of row j.
    let mut runs: Vec<(usize, usize, usize)> = Vec::new();
    let mut row_start = vec![0usize; h + 1];
    for (j, start) in row_start.iter_mut().take(h).enumerate() {
        *start = runs.len();
        let mut i = 0;
        while i < w {
            if member(j * w + i) {
                let a = i;
                while i < w && member(j * w + i) {
                    i += 1;
                }
                runs.push((j, a, i));
            } else {
                i += 1;
            }
        }
    }
    row_start[h] = runs.len();
    let mut parent: Vec<usize> = (0..runs.len()).collect();
    let reach = usize::from(eight);
    for j in 1..h {
        let (mut p, p_end) = (row_start[j - 1], row_start[j]);
        for r in row_start[j]..row_start[j + 1] {
            let (_, a, b) = runs[r];
            // Runs above that end before this one starts (with the diagonal reach) cannot touch it or later ones.
            while p < p_end && runs[p].2 + reach <= a {
                p += 1;
            }
            let mut q = p;
            while q < p_end && runs[q].1 < b + reach {
                let (x, y) = (find(&mut parent, r), find(&mut parent, q));
                if x != y {
                    // The root is always the earlier run: labels follow raster order.
                    parent[x.max(y)] = x.min(y);
                }
                q += 1;
            }
        }
    }
    let mut label = vec![0u32; w * h];
    let mut sizes = vec![0usize];
    let mut id_of = vec![0u32; runs.len()];
    for r in 0..runs.len() {
        let root = find(&mut parent, r);
        if root == r {
            id_of[r] = sizes.len() as u32;
            sizes.push(0);
        }
        let id = id_of[root];
        let (j, a, b) = runs[r];
        label[j * w + a..j * w + b].fill(id);
        sizes[id as usize] += b - a;
    }
    (label, sizes)
}

/// Pieces of the part smaller than this (mm²), and smaller than a twentieth of the largest, are debris.
const MIN_PIECE_MM2: f64 = 25.0;

/// How far outside a found hole's bounding box an unnamed steep region ("anomaly") is still taken for that hole's
/// wall, mm: the wall of a through-hole seen in perspective, and the half-lit stripes on its rim, lie within a
/// millimetre of the gap.
pub const HOLE_WALL_MARGIN_MM: f64 = 1.0;
/// Half-width (cells) of the thickest channel of missing data that cannot join a hole to the outside or to another
/// gap ([`detect`], step 3): 2 cells, so channels up to 4 cells (0.9 mm at the default grid, about two frames of
/// travel) wide.
pub const GAP_CHANNEL_CELLS: usize = 2;

/// Distance (cells, 3-4 chamfer: within 8% of Euclidean) of every cell to the nearest cell where `outside` holds.
fn distance_to(w: usize, h: usize, outside: impl Fn(usize) -> bool) -> Vec<f32> {
    let big = 3 * (w + h) as u32;
    let mut d: Vec<u32> = (0..w * h)
        .map(|k| if outside(k) { 0 } else { big })
        .collect();
    for j in 0..h {
        for i in 0..w {
            let k = j * w + i;
            let mut v = d[k];
            if i > 0 {
                v = v.min(d[k - 1] + 3);
            }
            if j > 0 {
                v = v.min(d[k - w] + 3);
                if i > 0 {
                    v = v.min(d[k - w - 1] + 4);
                }
                if i + 1 < w {
                    v = v.min(d[k - w + 1] + 4);
                }
            }
            d[k] = v;
        }
    }
    for j in (0..h).rev() {
        for i in (0..w).rev() {
            let k = j * w + i;
            let mut v = d[k];
            if i + 1 < w {
                v = v.min(d[k + 1] + 3);
            }
            if j + 1 < h {
                v = v.min(d[k + w] + 3);
                if i + 1 < w {
                    v = v.min(d[k + w + 1] + 4);
                }
                if i > 0 {
                    v = v.min(d[k + w - 1] + 4);
                }
            }
            d[k] = v;
        }
    }
    d.into_iter().map(|v| v as f32 / 3.0).collect()
}

/// A mask packed 64 cells to a word, row by row (`words` per row); bits past the last column stay clear.
struct Bits {
    w: usize,
    h: usize,
    words: usize,
    b: Vec<u64>,
}

impl Bits {
    fn pack(w: usize, h: usize, mask: &[bool], value: bool) -> Self {
        let words = w.div_ceil(64);
        let mut b = vec![0u64; words * h];
        for j in 0..h {
            for (q, chunk) in mask[j * w..(j + 1) * w].chunks(64).enumerate() {
                let mut word = 0u64;
                for (t, &m) in chunk.iter().enumerate() {
                    word |= u64::from(m == value) << t;
                }
                b[j * words + q] = word;
            }
        }
        Self { w, h, words, b }
    }

    fn unpack(&self, set: bool) -> Vec<bool> {
        let mut out = vec![!set; self.w * self.h];
        for j in 0..self.h {
            for (q, chunk) in out[j * self.w..(j + 1) * self.w].chunks_mut(64).enumerate() {
                let word = self.b[j * self.words + q];
                for (t, o) in chunk.iter_mut().enumerate() {
                    if (word >> t) & 1 == 1 {
                        *o = set;
                    }
                }
            }
        }
        out
    }

    /// The cells of the grid not in the set.
    fn complement(&mut self) {
        let tail = self.w % 64;
        for j in 0..self.h {
            for q in 0..self.words {
                let k = j * self.words + q;
                self.b[k] = !self.b[k];
                if q + 1 == self.words && tail != 0 {
                    self.b[k] &= (1u64 << tail) - 1;
                }
            }
        }
    }

    /// Dilation by a (2r+1)² square (r < 64), clipped to the grid.
    fn dilate(&self, r: usize) -> Self {
        let (words, h) = (self.words, self.h);
        let mut rows = vec![0u64; words * h];
        for j in 0..h {
            let line = &self.b[j * words..(j + 1) * words];
            for q in 0..words {
                let mut acc = line[q];
                for s in 1..=r {
                    // Towards higher columns (bit t moves to t + s) and towards lower ones.
                    acc |= line[q] << s;
                    if q > 0 {
                        acc |= line[q - 1] >> (64 - s);
                    }
                    acc |= line[q] >> s;
                    if q + 1 < words {
                        acc |= line[q + 1] << (64 - s);
                    }
                }
                rows[j * words + q] = acc;
            }
        }
        let tail = self.w % 64;
        let mut b = vec![0u64; words * h];
        for j in 0..h {
            for jj in j.saturating_sub(r)..(j + r + 1).min(h) {
                for q in 0..words {
                    b[j * words + q] |= rows[jj * words + q];
                }
            }
            if tail != 0 {
                b[j * words + words - 1] &= (1u64 << tail) - 1;
            }
        }
        Self {
            w: self.w,
            h,
            words,
            b,
        }
    }
}

/// Dilation (`grow`: a cell becomes `grow` when any cell of its (2r+1)² window is) or erosion (`!grow`: the same
/// for false cells), the window clipped to the grid; on bit-packed rows, 64 cells at a time. (Detection uses the
/// compositions [`closing`] and [`opening`], which stay packed in between.)
#[cfg(test)]
fn morph(w: usize, h: usize, mask: &[bool], r: usize, grow: bool) -> Vec<bool> {
    Bits::pack(w, h, mask, grow).dilate(r).unpack(grow)
}

/// Morphological closing of a mask by a (2r+1)² square: fills gaps up to 2r cells wide.
fn closing(w: usize, h: usize, mask: &[bool], r: usize) -> Vec<bool> {
    // Dilate the set, then erode it: dilate its complement within the grid and take the complement back.
    let mut d = Bits::pack(w, h, mask, true).dilate(r);
    d.complement();
    d.dilate(r).unpack(false)
}

/// Morphological opening (3 x 3) of a mask: removes structures one or two cells thin (the walls of a hole seen in
/// perspective land as such slivers inside it) and keeps everything broader unchanged.
fn opening(w: usize, h: usize, mask: &[bool]) -> Vec<bool> {
    opening_by(w, h, mask, 1)
}

/// Morphological opening of a mask by a (2r+1)² square: removes structures up to 2r cells thin.
fn opening_by(w: usize, h: usize, mask: &[bool], r: usize) -> Vec<bool> {
    // Erode (dilate the complement), then dilate what is left.
    let mut e = Bits::pack(w, h, mask, false).dilate(r);
    e.complement();
    e.dilate(r).unpack(true)
}

/// Per row, the first and last column where `mask` holds; None for empty rows.
fn row_extremes(w: usize, h: usize, mask: &[bool]) -> Vec<Option<(usize, usize)>> {
    (0..h)
        .map(|j| {
            let line = &mask[j * w..(j + 1) * w];
            let a = line.iter().position(|&m| m)?;
            let b = line.iter().rposition(|&m| m)?;
            Some((a, b))
        })
        .collect()
}

/// Per row, the [first, last] column inside the convex hull of the cells where `mask` holds (cell coordinates);
/// None for empty rows.
fn hull_rows(w: usize, h: usize, mask: &[bool]) -> Vec<Option<(f64, f64)>> {
    // Extreme cells per row are enough for the hull.
    let ext = row_extremes(w, h, mask);
    let mut pts: Vec<(f64, f64)> = Vec::new();
    for (j, e) in ext.iter().enumerate() {
        if let Some((a, b)) = *e {
            pts.push((a as f64, j as f64));
            pts.push((b as f64, j as f64));
        }
    }
    pts.sort_by(|p, q| p.0.total_cmp(&q.0).then(p.1.total_cmp(&q.1)));
    pts.dedup();
    let cross = |o: (f64, f64), a: (f64, f64), b: (f64, f64)| {
        (a.0 - o.0) * (b.1 - o.1) - (a.1 - o.1) * (b.0 - o.0)
    };
    let mut hull: Vec<(f64, f64)> = Vec::new();
    for pass in 0..2 {
        let start = hull.len();
        let iter: Box<dyn Iterator<Item = &(f64, f64)>> = if pass == 0 {
            Box::new(pts.iter())
        } else {
            Box::new(pts.iter().rev())
        };
        for &p in iter {
            while hull.len() >= start + 2
                && cross(hull[hull.len() - 2], hull[hull.len() - 1], p) <= 0.0
            {
                hull.pop();
            }
            hull.push(p);
        }
        hull.pop();
    }
    let mut rows = vec![None; h];
    if hull.len() < 3 {
        for (j, e) in ext.iter().enumerate() {
            rows[j] = e.map(|(a, b)| (a as f64, b as f64));
        }
        return rows;
    }
    for (j, row) in rows.iter_mut().enumerate() {
        let y = j as f64;
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for t in 0..hull.len() {
            let (a, b) = (hull[t], hull[(t + 1) % hull.len()]);
            if (a.1 - y) * (b.1 - y) > 0.0 {
                continue;
            }
            if a.1 == b.1 {
                lo = lo.min(a.0.min(b.0));
                hi = hi.max(a.0.max(b.0));
            } else {
                let x = a.0 + (y - a.1) / (b.1 - a.1) * (b.0 - a.0);
                lo = lo.min(x);
                hi = hi.max(x);
            }
        }
        if lo <= hi {
            *row = Some((lo, hi));
        }
    }
    rows
}

/// Raised cosine bell of unit height over radius `r0`: the smooth profile bumps and dents are measured with.
pub fn bell(d: f64, r0: f64) -> f64 {
    if d >= r0 {
        0.0
    } else {
        0.5 * (1.0 + (std::f64::consts::PI * d / r0).cos())
    }
}

/// A fitted bell: amplitude (signed), centre, radius, offset; and the RMS residual.
#[derive(Debug, Clone, Copy)]
struct BellFit {
    amplitude: f64,
    centre: [f64; 2],
    radius: f64,
    offset: f64,
    rms: f64,
}

/// Levenberg-Marquardt fit of `offset + amplitude * bell(|p − centre|, radius)` to samples (x, y, dev).
fn fit_bell(samples: &[(f64, f64, f64)], init: BellFit) -> Option<BellFit> {
    use nalgebra::{Matrix5, Vector5};
    let residuals = |p: &BellFit| -> f64 {
        samples
            .iter()
            .map(|&(x, y, z)| {
                let d = ((x - p.centre[0]).powi(2) + (y - p.centre[1]).powi(2)).sqrt();
                (z - p.offset - p.amplitude * bell(d, p.radius)).powi(2)
            })
            .sum()
    };
    let mut p = init;
    let mut cost = residuals(&p);
    let mut lambda = 1e-3;
    let pi = std::f64::consts::PI;
    for _ in 0..60 {
        let mut jtj = Matrix5::<f64>::zeros();
        let mut jtr = Vector5::<f64>::zeros();
        for &(x, y, z) in samples {
            let (ux, uy) = (x - p.centre[0], y - p.centre[1]);
            let d = (ux * ux + uy * uy).sqrt();
            let b = bell(d, p.radius);
            let r = z - p.offset - p.amplitude * b;
            let mut jac = Vector5::new(b, 0.0, 0.0, 0.0, 1.0);
            if d < p.radius && d > 1e-9 {
                let s = 0.5 * (pi * d / p.radius).sin() * pi / p.radius;
                jac[1] = p.amplitude * s * ux / d;
                jac[2] = p.amplitude * s * uy / d;
                jac[3] = p.amplitude * s * d / p.radius;
            }
            jtj += jac * jac.transpose();
            jtr += jac * r;
        }
        let mut improved = false;
        for _ in 0..10 {
            let mut a = jtj;
            for t in 0..5 {
                a[(t, t)] *= 1.0 + lambda;
                a[(t, t)] += 1e-12;
            }
            let Some(step) = a.lu().solve(&jtr) else {
                lambda *= 10.0;
                continue;
            };
            let q = BellFit {
                amplitude: p.amplitude + step[0],
                centre: [p.centre[0] + step[1], p.centre[1] + step[2]],
                radius: (p.radius + step[3]).max(0.05),
                offset: p.offset + step[4],
                rms: 0.0,
            };
            let c = residuals(&q);
            if c < cost {
                let small = (cost - c) < 1e-10 * cost.max(1e-12);
                p = q;
                cost = c;
                lambda = (lambda * 0.3).max(1e-9);
                improved = !small;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    p.rms = (cost / samples.len().max(1) as f64).sqrt();
    (p.amplitude.is_finite() && p.radius.is_finite()).then_some(p)
}

/// The dimensions of a region's cells: centroid weighted by `weight`, bounding box, and elongation.
struct Shape {
    centroid: [f64; 2],
    bbox: [f64; 4],
    elongation: f64,
}

fn shape(range: &RangeImage, cells: &[usize], weight: impl Fn(usize) -> f64) -> Shape {
    let w = range.width;
    let (mut sw, mut sx, mut sy) = (0.0, 0.0, 0.0);
    let mut bbox = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    let (hx, hy) = (range.spacing_mm[0] / 2.0, range.spacing_mm[1] / 2.0);
    for &k in cells {
        let (x, y) = cell_xy(range, k % w, k / w);
        let wt = weight(k).max(1e-12);
        sw += wt;
        sx += wt * x;
        sy += wt * y;
        bbox = [
            bbox[0].min(x - hx),
            bbox[1].min(y - hy),
            bbox[2].max(x + hx),
            bbox[3].max(y + hy),
        ];
    }
    let c = [sx / sw, sy / sw];
    // Unweighted second moments for the shape.
    let n = cells.len() as f64;
    let (mut mx, mut my) = (0.0, 0.0);
    for &k in cells {
        let (x, y) = cell_xy(range, k % w, k / w);
        mx += x;
        my += y;
    }
    let (mx, my) = (mx / n, my / n);
    let (mut cxx, mut cyy, mut cxy) = (0.0, 0.0, 0.0);
    for &k in cells {
        let (x, y) = cell_xy(range, k % w, k / w);
        cxx += (x - mx).powi(2);
        cyy += (y - my).powi(2);
        cxy += (x - mx) * (y - my);
    }
    // Each cell spreads over its own square: add its variance so single rows are not "infinitely thin".
    let cell_var = range.spacing_mm[0] * range.spacing_mm[1] / 12.0;
    let (cxx, cyy, cxy) = (cxx / n + cell_var, cyy / n + cell_var, cxy / n);
    let tr = cxx + cyy;
    let det = cxx * cyy - cxy * cxy;
    let disc = (tr * tr / 4.0 - det).max(0.0).sqrt();
    let (l1, l2) = (tr / 2.0 + disc, (tr / 2.0 - disc).max(1e-12));
    Shape {
        centroid: c,
        bbox,
        elongation: (l1 / l2).sqrt(),
    }
}

/// Finds, classifies and measures the defects of a characterized range image.
pub fn detect(
    range: &RangeImage,
    maps: &SurfaceMaps,
    rules: &mut SurfaceRules,
    params: &DetectParams,
) -> Result<Detection, CoreError> {
    let (w, h) = (range.width, range.height);
    if maps.class.len() != w * h {
        return Err(CoreError::InvalidParameter {
            field: "maps",
            value: maps.class.len().to_string(),
            reason: format!("characterization maps of another grid (this one is {w}x{h})"),
        });
    }
    let cell_area = range.spacing_mm[0] * range.spacing_mm[1];
    let mut out = Detection::default();
    // 1. The part: the largest 8-connected set of part cells.
    // Seams of missing cells (between the bands of neighbouring stripes, along shadows) must not split the part:
    // components are taken on the part mask closed over two cells.
    let is_part: Vec<bool> = maps.class.iter().map(|c| *c == CellClass::Part).collect();
    let closed = closing(w, h, &is_part, 2);
    let (plabel, psizes) = components(w, h, |k| closed[k], true);
    let Some(&main_size) = psizes.iter().skip(1).max() else {
        return Err(CoreError::Inspection {
            message:
                "the range image shows no part (nothing above the belt): nothing can be inspected"
                    .into(),
        });
    };
    // Every large piece is the part: a seam wider than the closing must not leave half the part uninspected.
    let min_piece = (main_size / 20)
        .max((MIN_PIECE_MM2 / cell_area) as usize)
        .min(main_size);
    let pieces: Vec<bool> = psizes.iter().map(|&n| n >= min_piece).collect();
    let in_part = |k: usize| plabel[k] != 0 && pieces[plabel[k] as usize];
    let piece_count = pieces.iter().skip(1).filter(|&&p| p).count();
    if piece_count > 1 {
        out.warnings.push(format!(
            "the part's surface falls into {piece_count} pieces separated by unmeasured strips: check the scan \
             (stripe coding, shadows)"
        ));
    }
    let main_part: Vec<bool> = (0..w * h).map(|k| in_part(k) && is_part[k]).collect();
    let opened = opening(w, h, &main_part);
    let on_part = |k: usize| opened[k];
    out.part_cells = opened.iter().filter(|&&p| p).count();
    if (main_size as f64) * cell_area < 4.0 {
        return Err(CoreError::Inspection {
            message: format!(
                "the part shows only {:.1} mm² of surface: too little to inspect (check the scan)",
                main_size as f64 * cell_area
            ),
        });
    }
    // The part running out of the measured area.
    // Only the two outermost rows and columns can touch.
    let band_rows = (0..h.min(2)).chain(h.saturating_sub(2).max(2)..h);
    let band_cols = (0..w.min(2)).chain(w.saturating_sub(2).max(2)..w);
    let row_hit = |j: usize| (0..w).any(|i| on_part(j * w + i));
    let col_hit = |i: usize| (0..h).any(|j| on_part(j * w + i));
    let mut touches = Vec::new();
    for j in band_rows {
        let side = if j <= 1 { "top (+y)" } else { "bottom (−y)" };
        if !touches.contains(&side) && row_hit(j) {
            touches.push(side);
        }
    }
    for i in band_cols {
        let side = if i <= 1 {
            "start of the scan (−x)"
        } else {
            "end of the scan (+x)"
        };
        if !touches.contains(&side) && col_hit(i) {
            touches.push(side);
        }
    }
    if !touches.is_empty() {
        out.warnings.push(format!(
            "the part runs out of the measured area at the {}: what lies beyond was not inspected",
            touches.join(", ")
        ));
    }
    // Rows and columns, never cell indices divided by the width: the part is most of the grid.
    let extremes = row_extremes(w, h, &opened);
    out.part_bbox_mm = extremes.iter().enumerate().fold(
        [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ],
        |b, (j, e)| {
            let Some((i0, i1)) = *e else { return b };
            let (x0, y) = cell_xy(range, i0, j);
            let (x1, _) = cell_xy(range, i1, j);
            let (hx, hy) = (range.spacing_mm[0] / 2.0, range.spacing_mm[1] / 2.0);
            [
                b[0].min(x0 - hx),
                b[1].min(y - hy),
                b[2].max(x1 + hx),
                b[3].max(y + hy),
            ]
        },
    );
    // Expected outline: the hull of the part, where the reference expects surface.
    let rows = hull_rows(w, h, &opened);
    let mut expected_mask = vec![false; w * h];
    for (j, row) in rows.iter().enumerate() {
        let Some((a, b)) = *row else { continue };
        let lo = (a - 1e-9).ceil().max(0.0) as usize;
        let hi = ((b + 1e-9).floor() as usize).min(w - 1);
        if lo <= hi {
            let span = j * w + lo..=j * w + hi;
            for (e, r) in expected_mask[span.clone()]
                .iter_mut()
                .zip(&maps.reference_mm[span])
            {
                *e = r.is_finite();
            }
        }
    }
    let expected = |k: usize| expected_mask[k];
    let expected_cells = expected_mask.iter().filter(|&&e| e).count();
    out.coverage = opened
        .iter()
        .zip(&expected_mask)
        .filter(|(p, e)| **p && **e)
        .count() as f64
        / expected_cells.max(1) as f64;
    // Distance to the part's edges and the rims of its gaps; seams narrower than the closing (a missing column
    // between two stripes' bands) are not edges: the surface on both sides of them is whole.
    let edge_dist = distance_to(w, h, |k| !in_part(k) || !closed[k]);
    let band = (params.edge_band_mm / range.spacing_mm[0].min(range.spacing_mm[1])) as f32;
    // What the scan's noise lets it see (module docs of `Detectable`), over the part away from its edges.
    let mut away: Vec<f64> = (0..w * h)
        .filter(|&k| on_part(k) && edge_dist[k] > band)
        .map(|k| f64::from(maps.smoothed_mm[k]))
        .filter(|v| v.is_finite())
        .collect();
    out.detectable = detectable(&mut away, params);
    let seed_mm = out.detectable.threshold_mm;
    let grow_mm = params.grow_mm * seed_mm / params.seed_mm;
    if out.detectable.raised {
        out.warnings.push(format!(
            "the method looks for deviations from {:.3} mm, but this scan's height noise ({:.4} mm, smoothed) lets \
             it tell only {seed_mm:.3} mm and more from noise: smaller bumps and dents cannot be seen, and the \
             threshold was raised to {seed_mm:.3} mm (a scan with less noise: a finer frame step, more light, a \
             matte surface)",
            params.seed_mm, out.detectable.noise_mm
        ));
    }
    // 2. Deviating regions by hysteresis, one sign at a time.
    let mut candidates: Vec<(Vec<usize>, f64)> = Vec::new();
    for sign in [1.0f32, -1.0] {
        let grow = |k: usize| on_part(k) && maps.smoothed_mm[k] * sign >= grow_mm as f32;
        let (label, sizes) = components(w, h, grow, true);
        let mut seeded = vec![false; sizes.len()];
        for k in 0..w * h {
            if label[k] != 0 && maps.smoothed_mm[k] * sign >= seed_mm as f32 && edge_dist[k] > band
            {
                seeded[label[k] as usize] = true;
            }
        }
        let mut cells: Vec<Vec<usize>> = vec![Vec::new(); sizes.len()];
        for k in 0..w * h {
            if label[k] != 0 && seeded[label[k] as usize] {
                cells[label[k] as usize].push(k);
            }
        }
        for c in cells.into_iter().filter(|c| !c.is_empty()) {
            if c.len() as f64 * cell_area >= params.min_area_mm2 {
                candidates.push((c, f64::from(sign)));
            }
        }
    }
    if candidates.len() > params.max_candidates {
        out.warnings.push(format!(
            "{} deviating regions: more than the {} evaluated; the reference surface probably does not fit this part \
             (use a golden scan or the product's model)",
            candidates.len(),
            params.max_candidates
        ));
        candidates.truncate(params.max_candidates);
    }
    for (cells, sign) in &candidates {
        let s = shape(range, cells, |k| f64::from(maps.deviation_mm[k]).abs());
        let (mut sum, mut sum_abs, mut curv) = (0.0, 0.0, 0.0f64);
        let mut peak = 0.0f64;
        let mut with_curvature = 0usize;
        for &k in cells {
            let d = f64::from(maps.deviation_mm[k]);
            if d.is_finite() {
                sum += d;
                sum_abs += d.abs();
                if d * sign > peak {
                    peak = d * sign;
                }
            }
            if let Some(g) = geometry_at(range, maps, k % w, k / w) {
                curv = curv.max(g.mean_curvature.abs());
                with_curvature += 1;
            }
        }
        if 2 * with_curvature < cells.len() {
            // Most of the region lies where the derivative window is incomplete (a narrow fragment between
            // gaps): bound its curvature from its height and size as a bell's top, pi² A / (2 r²).
            let r2 = cells.len() as f64 * cell_area / std::f64::consts::PI;
            curv = curv.max(std::f64::consts::PI.powi(2) * peak / (2.0 * r2));
        }
        let ev = Evidence {
            curvature_per_mm: curv,
            direction: if sum_abs > 0.0 { sum / sum_abs } else { 0.0 },
            gap_mm: 0.0,
            height_similarity_mm: 50.0,
            elongation: s.elongation,
            edge_notch_mm: 0.0,
            cells: cells.len(),
        };
        let area = cells.len() as f64 * cell_area;
        let (kind, confidence, reported) = weigh(
            &mut out,
            CandidateSource::Surface,
            s.centroid,
            area,
            ev,
            rules,
            params,
        )?;
        if reported && matches!(kind, DefectKind::Bump | DefectKind::Dent) {
            if let Some(step) = params.travel_step_mm.filter(|s| s.is_finite() && *s > 0.0) {
                let width = half_peak_travel_width(range, cells, &maps.deviation_mm, *sign, peak);
                if width < params.min_region_travel_steps * step {
                    // Not a surface the samples resolve: out of the candidates (learning never sees it) and into
                    // the unmeasured.
                    out.candidates.pop();
                    out.unmeasured.push(Unmeasured {
                        centroid_mm: s.centroid,
                        area_mm2: area,
                        reason: format!(
                            "{peak:.2} mm off the reference, but only {width:.2} mm wide along the travel at half \
                             that: under {} travel steps of {step:.2} mm, as one frame's misplaced samples are (a \
                             bump or dent 2 mm across is 1 mm wide there)",
                            params.min_region_travel_steps
                        ),
                    });
                    continue;
                }
            }
        }
        if !reported {
            // Small, steep and nameless: heights a wrong stripe index or a glint put there, not a surface.
            out.unmeasured.push(Unmeasured {
                centroid_mm: s.centroid,
                area_mm2: area,
                reason: format!(
                    "{peak:.2} mm off the reference over {area:.2} mm² with a curvature of {curv:.1}/mm: outlier \
                     heights, not a surface the rules can name"
                ),
            });
            continue;
        }
        let mut d = Defect {
            kind,
            centroid_mm: s.centroid,
            bbox_mm: s.bbox,
            area_mm2: area,
            depth_mm: peak,
            volume_mm3: sum_abs * cell_area,
            confidence,
            bottom_seen: true,
            evidence: ev,
        };
        if matches!(kind, DefectKind::Bump | DefectKind::Dent) {
            measure_bell(range, maps, &s, *sign, peak, grow_mm, &mut d);
        }
        if let Some(c) = out.candidates.last_mut() {
            c.defect = Some(out.defects.len());
        }
        out.defects.push(d);
    }
    // 3. Gaps: regions without part data that the outside cannot reach.
    let (olabel, _) = components(w, h, |k| !on_part(k), false);
    let mut outside_ids = std::collections::HashSet::new();
    for i in 0..w {
        outside_ids.insert(olabel[i]);
        outside_ids.insert(olabel[(h - 1) * w + i]);
    }
    for j in 0..h {
        outside_ids.insert(olabel[j * w]);
        outside_ids.insert(olabel[j * w + w - 1]);
    }
    let mut whole_gaps: std::collections::BTreeMap<u32, Vec<usize>> =
        std::collections::BTreeMap::new();
    for (k, &l) in olabel.iter().enumerate() {
        if l != 0 && !outside_ids.contains(&l) {
            whole_gaps.entry(l).or_default().push(k);
        }
    }
    // A thin channel of missing data (a stripe coding dropped for a frame or two: a column up to
    // 2 * GAP_CHANNEL_CELLS cells wide) is not part of a hole it touches: each gap is opened by a (2r+1)² square on
    // a window around it, and every core left is a gap of its own, given back the gap's cells within r of it (the
    // rim slivers the opening took) but no more of the channel. A gap that is all channel stays whole.
    let mut gaps: Vec<Vec<usize>> = Vec::new();
    for cells in whole_gaps.into_values() {
        let (mut i0, mut i1, mut j0, mut j1) = (w, 0, h, 0);
        for &k in &cells {
            let (i, j) = (k % w, k / w);
            i0 = i0.min(i);
            i1 = i1.max(i);
            j0 = j0.min(j);
            j1 = j1.max(j);
        }
        // One cell of margin, which is never the gap's (the gap is enclosed, so not on the grid's border).
        let (i0, j0) = (i0 - 1, j0 - 1);
        let (sw, sh) = (i1 + 2 - i0, j1 + 2 - j0);
        let mut member = vec![false; sw * sh];
        for &k in &cells {
            member[(k / w - j0) * sw + (k % w - i0)] = true;
        }
        let cores = opening_by(sw, sh, &member, GAP_CHANNEL_CELLS);
        let (clabel, csizes) = components(sw, sh, |q| cores[q], false);
        // No core (all channel), or one core that is the whole gap: the gap as it is.
        if csizes.len() < 2 || (csizes.len() == 2 && cores == member) {
            gaps.push(cells);
            continue;
        }
        let mut pieces: Vec<Vec<usize>> = vec![Vec::new(); csizes.len()];
        let r = GAP_CHANNEL_CELLS as isize;
        for &k in &cells {
            let (si, sj) = ((k % w - i0) as isize, (k / w - j0) as isize);
            let mut best: Option<(isize, u32)> = None;
            for dj in -r..=r {
                for di in -r..=r {
                    let (ii, jj) = (si + di, sj + dj);
                    if ii < 0 || jj < 0 || ii >= sw as isize || jj >= sh as isize {
                        continue;
                    }
                    let l = clabel[jj as usize * sw + ii as usize];
                    let d = di.abs().max(dj.abs());
                    if l != 0 && best.is_none_or(|(bd, _)| d < bd) {
                        best = Some((d, l));
                    }
                }
            }
            if let Some((_, l)) = best {
                pieces[l as usize].push(k);
            }
        }
        gaps.extend(pieces.into_iter().filter(|p| !p.is_empty()));
    }
    for cells in &gaps {
        let area = cells.len() as f64 * cell_area;
        if area < params.min_gap_mm2 {
            continue;
        }
        let expected_share = cells
            .iter()
            .filter(|&&k| maps.reference_mm[k].is_finite())
            .count() as f64
            / cells.len() as f64;
        if expected_share < 0.5 {
            // The reference has no surface here either: a designed opening.
            continue;
        }
        let s = shape(range, cells, |_| 1.0);
        // Ring: part cells within two cells of the gap.
        // Ring: part cells beyond the rim band (half-lit stripes, walls seen in perspective), three cells deep;
        // distances on a window around the gap only.
        let ring_lo = band.max(1.0);
        let ring_hi = ring_lo + 3.0;
        let (bi0, bj0, bi1, bj1) = bbox_cells(range, &s.bbox, ring_hi.ceil() as usize + 1);
        let (ww, wh) = (bi1 - bi0, bj1 - bj0);
        let mut in_gap = vec![false; ww * wh];
        for &k in cells {
            let (i, j) = (k % w, k / w);
            if (bi0..bi1).contains(&i) && (bj0..bj1).contains(&j) {
                in_gap[(j - bj0) * ww + (i - bi0)] = true;
            }
        }
        let near = distance_to(ww, wh, |k| in_gap[k]);
        let (mut left, mut right, mut top, mut bottom) = (vec![], vec![], vec![], vec![]);
        let (ci, cj) = (
            (s.centroid[0] - range.origin_mm[0]) / range.spacing_mm[0],
            (range.origin_mm[1] - s.centroid[1]) / range.spacing_mm[1],
        );
        for j in bj0..bj1 {
            for i in bi0..bi1 {
                let k = j * w + i;
                let dist = near[(j - bj0) * ww + (i - bi0)];
                if dist < ring_lo || dist > ring_hi || !on_part(k) {
                    continue;
                }
                let d = f64::from(maps.deviation_mm[k]);
                if !d.is_finite() {
                    continue;
                }
                if (i as f64) < ci {
                    left.push(d)
                } else {
                    right.push(d)
                }
                if (j as f64) < cj {
                    top.push(d)
                } else {
                    bottom.push(d)
                }
            }
        }
        let similarity =
            if left.is_empty() || right.is_empty() || top.is_empty() || bottom.is_empty() {
                50.0
            } else {
                (median(&mut left) - median(&mut right))
                    .abs()
                    .max((median(&mut top) - median(&mut bottom)).abs())
            };
        let ev = Evidence {
            curvature_per_mm: 0.0,
            direction: 0.0,
            gap_mm: 2.0 * (area / std::f64::consts::PI).sqrt(),
            height_similarity_mm: similarity,
            elongation: s.elongation,
            edge_notch_mm: 0.0,
            cells: cells.len(),
        };
        let (kind, confidence, reported) = weigh(
            &mut out,
            CandidateSource::Gap,
            s.centroid,
            area,
            ev,
            rules,
            params,
        )?;
        if !reported {
            out.unmeasured.push(Unmeasured {
                centroid_mm: s.centroid,
                area_mm2: area,
                reason: if similarity >= 50.0 {
                    "no data and the surface around it is not measured on every side".into()
                } else if similarity > 0.5 {
                    format!("no data, with {similarity:.2} mm between the heights on either side (a shadow or an edge)")
                } else {
                    gap_reason(rules, &ev, confidence, params)
                },
            });
            continue;
        }
        // Depth: the reference over the lowest surface seen inside (the belt when nothing is seen).
        let mut refs: Vec<f64> = cells
            .iter()
            .map(|&k| f64::from(maps.reference_mm[k]))
            .filter(|v| v.is_finite())
            .collect();
        let seen: Vec<f64> = cells
            .iter()
            .map(|&k| f64::from(range.z[k]))
            .filter(|v| v.is_finite())
            .collect();
        // A bottom is seen when much of the gap holds heights (a few wall samples are not a bottom).
        let bottom_seen = seen.len() as f64 >= params.min_seen_share * cells.len() as f64;
        let floor = if bottom_seen {
            let mut seen = seen;
            median(&mut seen).max(0.0)
        } else {
            0.0
        };
        let reference = median(&mut refs);
        // A gap whose cells mostly hold the surface's own heights is a seam of missing samples (measured strips too
        // thin for the part's mask between them), not a hole.
        if bottom_seen && reference - floor < params.seed_mm {
            out.unmeasured.push(Unmeasured {
                centroid_mm: s.centroid,
                area_mm2: area,
                reason: format!(
                    "no data in strips, the cells between them at the surface's own height ({:+.3} mm): not a hole",
                    floor - reference
                ),
            });
            continue;
        }
        if let Some(c) = out.candidates.last_mut() {
            c.defect = Some(out.defects.len());
        }
        let measured = hole_area(range, cells, params.travel_step_mm);
        out.defects.push(Defect {
            kind,
            centroid_mm: s.centroid,
            bbox_mm: s.bbox,
            area_mm2: measured,
            depth_mm: reference - floor,
            volume_mm3: refs.iter().map(|r| (r - floor).max(0.0)).sum::<f64>()
                * cell_area
                * (measured / area),
            confidence,
            bottom_seen,
            evidence: ev,
        });
    }
    // 4. Edge chips: expected cells, not the part, open to the outside.
    let chip = |k: usize| !on_part(k) && expected(k) && outside_ids.contains(&olabel[k]);
    let (clabel, csizes) = components(w, h, chip, false);
    if csizes.len() > 1 {
        let depth = distance_to(w, h, |k| !expected(k));
        let mut cells: Vec<Vec<usize>> = vec![Vec::new(); csizes.len()];
        for k in 0..w * h {
            if clabel[k] != 0 {
                cells[clabel[k] as usize].push(k);
            }
        }
        for c in cells
            .iter()
            .filter(|c| c.len() as f64 * cell_area >= params.min_gap_mm2)
        {
            let notch = f64::from(c.iter().map(|&k| depth[k]).fold(0.0f32, f32::max))
                * range.spacing_mm[0].min(range.spacing_mm[1]);
            let s = shape(range, c, |_| 1.0);
            let ev = Evidence {
                curvature_per_mm: 0.0,
                direction: 0.0,
                gap_mm: 0.0,
                height_similarity_mm: 50.0,
                elongation: s.elongation,
                edge_notch_mm: notch,
                cells: c.len(),
            };
            let area = c.len() as f64 * cell_area;
            // Missing material shows the belt (or a lower surface) where the part should be; a notch of cells
            // without any data is missing measurement, not missing material.
            let seen = c
                .iter()
                .filter(|&&k| maps.class[k] == CellClass::Belt)
                .count();
            if (seen as f64) < params.min_seen_share * c.len() as f64 {
                if ev.edge_notch_mm >= params.edge_band_mm {
                    out.unmeasured.push(Unmeasured {
                        centroid_mm: s.centroid,
                        area_mm2: area,
                        reason: format!(
                            "no data {notch:.2} mm into the part's outline (the belt is not seen there either)"
                        ),
                    });
                }
                continue;
            }
            let (kind, confidence, reported) = weigh(
                &mut out,
                CandidateSource::Edge,
                s.centroid,
                area,
                ev,
                rules,
                params,
            )?;
            if !reported {
                continue;
            }
            let mut refs: Vec<f64> = c
                .iter()
                .map(|&k| f64::from(maps.reference_mm[k]))
                .filter(|v| v.is_finite())
                .collect();
            let area = c.len() as f64 * cell_area;
            if let Some(c) = out.candidates.last_mut() {
                c.defect = Some(out.defects.len());
            }
            out.defects.push(Defect {
                kind,
                centroid_mm: s.centroid,
                bbox_mm: s.bbox,
                area_mm2: area,
                depth_mm: median(&mut refs),
                volume_mm3: refs.iter().sum::<f64>() * cell_area,
                confidence,
                bottom_seen: false,
                evidence: ev,
            });
        }
    }
    if out.coverage < 0.9 {
        out.warnings.push(format!(
            "only {:.0}% of the part's outline holds data: unmeasured surface cannot be judged",
            100.0 * out.coverage
        ));
    }
    // A hole's wall: a steep region the rules cannot name ("anomaly") that lies within a found hole's box (plus a
    // margin) is the wall of that hole seen in perspective, not a defect of its own. Measured on the defect benchmark:
    // every false defect left after stripe coding settled its near ties was such a wall.
    let holes: Vec<[f64; 4]> = out
        .defects
        .iter()
        .filter(|d| d.kind == DefectKind::Hole)
        .map(|d| d.bbox_mm)
        .collect();
    let wall = |d: &Defect| {
        let [x, y] = d.centroid_mm;
        let m = HOLE_WALL_MARGIN_MM;
        d.kind == DefectKind::Anomaly
            && holes
                .iter()
                .any(|b| x >= b[0] - m && x <= b[2] + m && y >= b[1] - m && y <= b[3] + m)
    };
    // A piece of a bump or dent: a smaller one of the same kind whose centre lies within a larger one's fitted
    // footprint is part of it (a seam or a column of wrong heights split the region; the bell fit of the larger
    // piece already measures the whole). Traced on the demo: a 2.5 mm² "dent" 1.4 mm from the centre of the 5 mm
    // dent.
    let piece = |k: usize| {
        let d = &out.defects[k];
        matches!(d.kind, DefectKind::Bump | DefectKind::Dent)
            && out.defects.iter().enumerate().any(|(o, e)| {
                o != k
                    && e.kind == d.kind
                    && e.area_mm2 > d.area_mm2
                    && (e.centroid_mm[0] - d.centroid_mm[0])
                        .hypot(e.centroid_mm[1] - d.centroid_mm[1])
                        < (e.area_mm2 / std::f64::consts::PI).sqrt()
            })
    };
    let keep: Vec<bool> = (0..out.defects.len())
        .map(|k| !wall(&out.defects[k]) && !piece(k))
        .collect();
    // Stable report order (y descending, then x); candidates keep pointing at their defects.
    let mut order: Vec<usize> = (0..out.defects.len()).filter(|&k| keep[k]).collect();
    order.sort_by(|&a, &b| {
        let (a, b) = (&out.defects[a], &out.defects[b]);
        b.centroid_mm[1]
            .total_cmp(&a.centroid_mm[1])
            .then(a.centroid_mm[0].total_cmp(&b.centroid_mm[0]))
    });
    let mut new_index = vec![None; out.defects.len()];
    for (new, &old) in order.iter().enumerate() {
        new_index[old] = Some(new);
    }
    out.defects = order.iter().map(|&k| out.defects[k].clone()).collect();
    for c in &mut out.candidates {
        c.defect = c.defect.and_then(|k| new_index[k]);
        c.reported = c.defect.is_some();
    }
    Ok(out)
}

/// Everything inspection computes for one range image.
#[derive(Debug, Clone)]
pub struct Inspection {
    /// The reference used.
    pub reference: ReferenceInfo,
    /// Characterization maps.
    pub maps: SurfaceMaps,
    /// What was found.
    pub detection: Detection,
    /// Cells removed as outlier heights before characterization.
    pub outliers: usize,
}

/// Characterizes `range` against the reference from `source` and detects its defects.
pub fn inspect(
    range: &RangeImage,
    source: ReferenceSource<'_>,
    characterize: &CharacterizeParams,
    rules: &mut SurfaceRules,
    params: &DetectParams,
) -> Result<Inspection, CoreError> {
    if range.width == 0 || range.height == 0 || range.z.len() != range.width * range.height {
        return Err(CoreError::Inspection {
            message: format!(
                "the range image is empty or inconsistent ({}x{} cells, {} values)",
                range.width,
                range.height,
                range.z.len()
            ),
        });
    }
    if range.measured() == 0 {
        return Err(CoreError::Inspection {
            message:
                "the range image holds no measurement at all (every cell is NaN): nothing was seen"
                    .into(),
        });
    }
    let mut cleaned = range.clone();
    let outliers = remove_outliers(&mut cleaned, params.outlier_mm);
    // A golden scan is a scan too: its wrong-index fragments would stand in the reference as pits or spikes that
    // every part then "has". It is cleaned the same way (`PreparedGolden`; once for many parts when the caller
    // prepares it).
    let prepared = match source {
        ReferenceSource::Golden(golden) => Some(PreparedGolden::new(
            golden,
            params.outlier_mm,
            characterize.belt_level_mm,
            params.travel_step_mm,
        )),
        ReferenceSource::Prepared(p) => {
            p.check(
                params.outlier_mm,
                characterize.belt_level_mm,
                params.travel_step_mm,
            )?;
            None
        }
        ReferenceSource::Fit(_) => None,
    };
    let source = match &prepared {
        Some(p) => ReferenceSource::Prepared(p),
        None => source,
    };
    let (heights, reference) =
        reference_heights(&cleaned, source, characterize, params.travel_step_mm)?;
    let maps = surface_maps(&cleaned, heights, characterize)?;
    let detection = detect(&cleaned, &maps, rules, params)?;
    Ok(Inspection {
        reference,
        maps,
        detection,
        outliers,
    })
}

/// Why a gap with the same heights on either side was not called a hole: narrower than the scan's sampling can tell
/// from missing samples ([`DetectParams::min_hole_travel_steps`]), or as the rule base's terms say: too small, oblong
/// (a band of missing samples), too large, or a certainty below the threshold.
fn gap_reason(
    rules: &SurfaceRules,
    ev: &Evidence,
    confidence: f64,
    params: &DetectParams,
) -> String {
    let is =
        |input: &str, term: &str, x: f64| rules.degree(input, term, x).is_some_and(|d| d >= 0.5);
    if let (true, Some(step)) = (below_sampling(ev, params), params.travel_step_mm) {
        format!(
            "no data over {:.1} mm, less than {} travel steps of {step:.2} mm: too small to tell a hole from samples \
             missing for a few frames",
            ev.gap_mm, params.min_hole_travel_steps
        )
    } else if is("gap", "none", ev.gap_mm) {
        format!(
            "no data over {:.1} mm: a few empty cells, not a hole",
            ev.gap_mm
        )
    } else if is("elongation", "oblong", ev.elongation) {
        format!(
            "no data over {:.1} mm, {:.1} times as long as wide: a band of missing samples, not a hole",
            ev.gap_mm, ev.elongation
        )
    } else if is("gap", "too_large", ev.gap_mm) {
        format!(
            "no data over {:.1} mm (too large a gap to call a hole)",
            ev.gap_mm
        )
    } else {
        format!(
            "no data over {:.1} mm: called a hole with certainty {confidence:.2} only (at least {:.2} needed)",
            ev.gap_mm, params.min_confidence
        )
    }
}

/// Cell index ranges (i0, j0, i1, j1) covering `bbox` plus `margin` cells, clamped to the grid.
fn bbox_cells(range: &RangeImage, bbox: &[f64; 4], margin: usize) -> (usize, usize, usize, usize) {
    let ci = |x: f64| ((x - range.origin_mm[0]) / range.spacing_mm[0]).round();
    let cj = |y: f64| ((range.origin_mm[1] - y) / range.spacing_mm[1]).round();
    let clamp = |v: f64, n: usize| v.clamp(0.0, n as f64) as usize;
    let m = margin as f64;
    (
        clamp(ci(bbox[0]) - m, range.width),
        clamp(cj(bbox[3]) - m, range.height),
        clamp(ci(bbox[2]) + m + 1.0, range.width),
        clamp(cj(bbox[1]) + m + 1.0, range.height),
    )
}

/// Measures a bump or dent by fitting a bell to the deviation around it; keeps the region's figures when the fit
/// fails or is implausible.
fn measure_bell(
    range: &RangeImage,
    maps: &SurfaceMaps,
    s: &Shape,
    sign: f64,
    peak: f64,
    grow_mm: f64,
    d: &mut Defect,
) {
    let w = range.width;
    let size = (s.bbox[2] - s.bbox[0]).max(s.bbox[3] - s.bbox[1]);
    let margin = ((size.max(2.0)) / range.spacing_mm[0].min(range.spacing_mm[1])).ceil() as usize;
    let (i0, j0, i1, j1) = bbox_cells(range, &s.bbox, margin);
    let mut samples = Vec::new();
    for j in j0..j1 {
        for i in i0..i1 {
            let v = f64::from(maps.deviation_mm[j * w + i]);
            if v.is_finite() {
                let (x, y) = cell_xy(range, i, j);
                samples.push((x, y, v));
            }
        }
    }
    if samples.len() < 12 || peak <= 0.0 {
        return;
    }
    // Initial radius from the region's size at the growth threshold: a bell is above t out to
    // r0 * acos(2 t / A − 1) / pi.
    let dt = (d.area_mm2 / std::f64::consts::PI).sqrt();
    let frac = (2.0 * grow_mm / peak - 1.0).clamp(-1.0, 1.0);
    let r0 = if frac < 0.999 {
        dt * std::f64::consts::PI / frac.acos()
    } else {
        dt
    };
    let init = BellFit {
        amplitude: sign * peak,
        centre: s.centroid,
        radius: r0.max(0.3),
        offset: 0.0,
        rms: 0.0,
    };
    let Some(f) = fit_bell(&samples, init) else {
        return;
    };
    let plausible = f.amplitude * sign > 0.0
        && f.radius > 0.3
        && f.radius < 3.0 * r0.max(1.0)
        && (f.centre[0] - s.centroid[0]).hypot(f.centre[1] - s.centroid[1]) < r0.max(1.0)
        && f.rms < 0.5 * f.amplitude.abs();
    if !plausible {
        return;
    }
    let cell_area = range.spacing_mm[0] * range.spacing_mm[1];
    let volume: f64 = samples
        .iter()
        .filter(|&&(x, y, _)| (x - f.centre[0]).hypot(y - f.centre[1]) < f.radius)
        .map(|&(_, _, v)| ((v - f.offset) * sign).max(0.0))
        .sum::<f64>()
        * cell_area;
    d.centroid_mm = f.centre;
    d.area_mm2 = std::f64::consts::PI * f.radius * f.radius;
    d.depth_mm = f.amplitude.abs();
    d.volume_mm3 = volume;
    d.bbox_mm = [
        f.centre[0] - f.radius,
        f.centre[1] - f.radius,
        f.centre[0] + f.radius,
        f.centre[1] + f.radius,
    ];
}

/// A measured cell beside a hole's gap holds a partly lit sheet when its intensity is below this fraction of the
/// intensity along its grid row beyond it ([`RIM_REFERENCE_MM`]; the same stripe on the same surface a few frames
/// away). A sheet (`laser.sigma_mm` wide) whose centre has passed the rim still lights the surface up to the rim:
/// the part of its profile left is dim, its sample sits at the rim, and the gap there is not a travel step's
/// sampling short of it. Its peak falls below half the whole sheet's once the centre lies more than 1.18 sigma
/// beyond the rim.
pub const RIM_PARTIAL_FRACTION: f32 = 0.5;
/// How far along its grid row, beyond a gap's end, the intensity a rim cell is compared with is taken (the median of
/// the measured cells there), mm: about four samples at 0.5 mm a frame.
pub const RIM_REFERENCE_MM: f64 = 2.0;

/// The area of a gap (cells of the range image), mm², corrected for the sampling along x when the travel step is
/// known: on each grid row, a run of gap cells that ends on measured surface ends on average half a step minus
/// half a cell outside the true edge (the last sample before the edge lies uniformly within one step of it, and a
/// sample's cell reaches half a cell beyond it), so the run is shortened by that much at each such end — unless the
/// range image's intensities show that end's cell to hold a partly lit sheet ([`RIM_PARTIAL_FRACTION`]), whose
/// sample sits at the rim itself: there the run is lengthened by half a cell instead (that cell reaches half a cell
/// into the hole). Measured on `stripe3d bench defects`: holes' median area error by diameter -6.3% to -2.3% with
/// every end shortened, -1.1% to +1.3% with partly lit ends told apart.
fn hole_area(range: &RangeImage, cells: &[usize], travel_step_mm: Option<f64>) -> f64 {
    let cell_area = range.spacing_mm[0] * range.spacing_mm[1];
    let raw = cells.len() as f64 * cell_area;
    let Some(step) = travel_step_mm.filter(|s| s.is_finite() && *s > 0.0) else {
        return raw;
    };
    let dx = range.spacing_mm[0];
    let excess = (0.5 * (step - dx)).max(0.0) / dx; // cells at each measured end
    if excess == 0.0 || cells.is_empty() {
        return raw;
    }
    let w = range.width;
    let measured = |i: usize, j: usize| range.z[j * w + i].is_finite();
    let intensity = range
        .intensity
        .as_deref()
        .filter(|v| v.len() == range.z.len());
    let reach = (RIM_REFERENCE_MM / dx).round().max(1.0) as usize;
    let mut around = Vec::new();
    // Whether the measured cell (i, j), a gap's end, holds a partly lit sheet: dimmer than the cells beyond it along
    // the row (`dir` +1 or -1, away from the gap) by more than `RIM_PARTIAL_FRACTION`.
    let mut partial = |i: usize, j: usize, dir: isize| -> bool {
        let Some(v) = intensity else {
            return false;
        };
        let at = v[j * w + i];
        around.clear();
        let mut c = i as isize;
        for _ in 0..reach {
            c += dir;
            if c < 0 || c >= w as isize || !measured(c as usize, j) {
                break;
            }
            let x = v[j * w + c as usize];
            if x.is_finite() {
                around.push(x);
            }
        }
        if around.len() < reach / 2 || !at.is_finite() {
            return false;
        }
        let mid = around.len() / 2;
        let reference = *around.select_nth_unstable_by(mid, f32::total_cmp).1;
        at < RIM_PARTIAL_FRACTION * reference
    };
    let mut sorted = cells.to_vec();
    sorted.sort_unstable();
    let mut total = 0.0;
    let mut k = 0;
    while k < sorted.len() {
        // A run of consecutive cells on one grid row.
        let (j, i0) = (sorted[k] / w, sorted[k] % w);
        let mut i1 = i0;
        while k + 1 < sorted.len() && sorted[k + 1] == j * w + i1 + 1 && i1 + 1 < w {
            k += 1;
            i1 += 1;
        }
        k += 1;
        // Cells to take off at an end: the expected excess after a full sheet's sample; half a cell back on after a
        // partly lit one's (its sample sits at the rim, and its cell reaches half a cell into the hole).
        let mut end = |i: usize, dir: isize| -> f64 {
            if !measured(i, j) {
                0.0
            } else if partial(i, j, dir) {
                -0.5
            } else {
                excess
            }
        };
        let mut cut = 0.0;
        if i0 > 0 {
            cut += end(i0 - 1, -1);
        }
        if i1 + 1 < w {
            cut += end(i1 + 1, 1);
        }
        let len = (i1 - i0 + 1) as f64;
        total += (len - cut).max(0.0);
    }
    total * cell_area
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::VecDeque;

    #[test]
    fn hole_areas_are_corrected_for_the_travel_step() {
        use crate::accumulate::{Profile, ProfilePoint, RangeGrid, RangeParams};
        // A 10 mm plate with a 2.5 mm x 4.4 mm slot, sampled as one stripe sweeps it: every 0.5 mm along x (at
        // one phase for the whole scan), on every grid row; no sample falls in the slot. (A slot, not a round
        // hole: where a round hole's chord is shorter than the accumulation's fill distance, its caps are filled
        // over and lost, which no correction of the measured rows can see.)
        let (step, w, h) = (0.5, 2.5, 4.4);
        let truth = w * h;
        let (mut raw_err, mut corrected_err) = (0.0f64, 0.0f64);
        let phases = [0.0, 0.1, 0.2, 0.3, 0.4];
        for phase in phases {
            let profiles: Vec<Profile> = (0..40)
                .map(|k| {
                    let x = -10.0 + phase + k as f64 * step;
                    Profile {
                        frame: k,
                        travel_mm: k as f64 * step,
                        points: (0..100)
                            .map(|row| (row, -11.11 + 0.22 * row as f64))
                            .filter(|&(_, y)| x.abs() > 0.5 * w || y.abs() > 0.5 * h)
                            .map(|(row, y)| ProfilePoint {
                                stripe: 0,
                                row,
                                u: 0.0,
                                x_mm: x,
                                y_mm: y,
                                z_mm: 10.0,
                                intensity: 100.0,
                                spacetime: false,
                            })
                            .collect(),
                    }
                })
                .collect();
            let params = RangeParams {
                spacing_mm: [0.22, 0.22],
                ..RangeParams::default()
            };
            let mut grid = RangeGrid::covering(&profiles, params).expect("grid");
            grid.accumulate(&profiles);
            let range = grid.image();
            // The slot: the unmeasured cells within 4 mm of its centre.
            let slot: Vec<usize> = (0..range.width * range.height)
                .filter(|&k| {
                    let x = range.origin_mm[0] + (k % range.width) as f64 * 0.22;
                    let y = range.origin_mm[1] - (k / range.width) as f64 * 0.22;
                    x.hypot(y) < 4.0 && range.z[k].is_nan()
                })
                .collect();
            let n = phases.len() as f64;
            raw_err += (hole_area(&range, &slot, None) - truth) / truth / n;
            corrected_err += (hole_area(&range, &slot, Some(step)) - truth) / truth / n;
        }
        // Uncorrected, the slot is one step less a cell longer along x than it is (0.28 mm on 2.5: +11%).
        assert!(raw_err > 0.08, "raw {raw_err}, corrected {corrected_err}");
        assert!(
            corrected_err.abs() < 0.03,
            "corrected {corrected_err}, raw {raw_err}"
        );
    }

    #[test]
    fn a_partly_lit_sheet_at_a_rim_is_not_taken_for_a_travel_steps_sampling() {
        // One grid row of 0.1 mm cells: plate, a gap of 20 cells, plate; 100 grey levels everywhere but the cell
        // left of the gap (a partly lit sheet's sample, 30) when `dim`. Travel step 0.5 mm: a full sheet's end
        // loses (0.5 - 0.1) / 2 = 0.2 mm = 2 cells.
        let row = |dim: bool, intensities: bool| {
            let w = 60;
            let mut z = vec![10.0f32; w];
            let mut i = vec![100.0f32; w];
            for k in 20..40 {
                z[k] = f32::NAN;
                i[k] = f32::NAN;
            }
            if dim {
                i[19] = 30.0;
            }
            RangeImage {
                origin_mm: [0.0, 0.0],
                spacing_mm: [0.1, 0.1],
                width: w,
                height: 1,
                z,
                intensity: intensities.then_some(i),
            }
        };
        let gap: Vec<usize> = (20..40).collect();
        let cells = |r: &RangeImage| hole_area(r, &gap, Some(0.5)) / 0.01;
        // Two full ends: 20 - 2 - 2 cells.
        assert!((cells(&row(false, true)) - 16.0).abs() < 1e-9);
        // A partly lit sheet at the left rim: no excess there, and half its cell back (it reaches into the hole).
        assert!(
            (cells(&row(true, true)) - 18.5).abs() < 1e-9,
            "{}",
            cells(&row(true, true))
        );
        // Without intensities nothing tells: both ends are full sheets'.
        assert!((cells(&row(true, false)) - 16.0).abs() < 1e-9);
        // A dim cell whose row holds too little beyond it to compare with is taken as a full sheet's.
        let mut short = row(true, true);
        for k in 0..15 {
            short.z[k] = f32::NAN;
        }
        assert!((cells(&short) - 16.0).abs() < 1e-9, "{}", cells(&short));
    }

    const NEIGHBOURS8: [(i64, i64); 8] = [
        (-1, 0),
        (1, 0),
        (0, -1),
        (0, 1),
        (-1, -1),
        (1, -1),
        (-1, 1),
        (1, 1),
    ];

    /// Breadth-first labelling: the slow, obviously correct reference of [`components`].
    fn components_bfs(w: usize, h: usize, mask: &[bool], eight: bool) -> (Vec<u32>, Vec<usize>) {
        let mut label = vec![0u32; w * h];
        let mut sizes = vec![0usize];
        let mut queue = VecDeque::new();
        for start in 0..w * h {
            if label[start] != 0 || !mask[start] {
                continue;
            }
            let id = sizes.len() as u32;
            let mut n = 0usize;
            label[start] = id;
            queue.push_back(start);
            while let Some(k) = queue.pop_front() {
                n += 1;
                let (i, j) = ((k % w) as i64, (k / w) as i64);
                for (di, dj) in NEIGHBOURS8 {
                    if !eight && di != 0 && dj != 0 {
                        continue;
                    }
                    let (a, b) = (i + di, j + dj);
                    if a < 0 || b < 0 || a >= w as i64 || b >= h as i64 {
                        continue;
                    }
                    let kk = b as usize * w + a as usize;
                    if label[kk] == 0 && mask[kk] {
                        label[kk] = id;
                        queue.push_back(kk);
                    }
                }
            }
            sizes.push(n);
        }
        (label, sizes)
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(500))]
        /// The run-based labelling equals breadth-first search, label for label, in 4 and 8 connectivity.
        #[test]
        fn run_labelling_equals_breadth_first_search(
            w in 1usize..24,
            h in 1usize..24,
            density in 0.0f64..1.0,
            seed in 0u64..1_000_000,
        ) {
            let mut x = seed.wrapping_mul(6364136223846793005).wrapping_add(1);
            let mask: Vec<bool> = (0..w * h)
                .map(|_| {
                    x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                    ((x >> 33) as f64 / (1u64 << 31) as f64) < density
                })
                .collect();
            for eight in [false, true] {
                let fast = components(w, h, |k| mask[k], eight);
                let slow = components_bfs(w, h, &mask, eight);
                proptest::prop_assert_eq!(&fast, &slow, "eight = {}", eight);
            }
        }
    }
    use crate::characterize::{CharacterizeParams, fit_reference, surface_maps};

    /// A 40 x 30 mm, 10 mm plate on the belt on a 0.2 mm grid, with `f` added to its top.
    fn plate(f: impl Fn(f64, f64) -> Option<f64>) -> RangeImage {
        let (w, h) = (250, 200);
        let mut r = RangeImage {
            origin_mm: [-25.0, 20.0],
            spacing_mm: [0.2, 0.2],
            width: w,
            height: h,
            z: vec![0.0; w * h],
            intensity: None,
        };
        for j in 0..h {
            for i in 0..w {
                let (x, y) = cell_xy(&r, i, j);
                let on = x.abs() <= 20.0 && y.abs() <= 15.0;
                // Deterministic pseudo-noise of about 0.007 mm.
                let n = (((i * 7919 + j * 104_729) % 1000) as f64 / 1000.0 - 0.5) * 0.024;
                r.z[j * w + i] = if on {
                    match f(x, y) {
                        Some(dz) => (10.0 + dz + n) as f32,
                        None => f32::NAN,
                    }
                } else {
                    n.abs() as f32
                };
            }
        }
        r
    }

    /// The characterization maps of `r` against its fitted plane.
    fn plane_maps(r: &RangeImage) -> SurfaceMaps {
        let p = CharacterizeParams::default();
        let reference = fit_reference(r, &p).expect("fit");
        surface_maps(r, reference.heights(r), &p).expect("maps")
    }

    fn run(r: &RangeImage) -> Detection {
        let mut rules = SurfaceRules::shipped().expect("rules");
        detect(r, &plane_maps(r), &mut rules, &DetectParams::default()).expect("detect")
    }

    #[test]
    fn a_holes_wall_is_part_of_the_hole_not_an_anomaly() {
        // A 6 mm through-hole whose far wall is seen in perspective: a crescent inside the hole's right rim where the
        // heights fall steeply from the surface towards the belt.
        let r = plate(|x, y| {
            let d = x.hypot(y);
            if d >= 3.0 {
                Some(0.0)
            } else if x > 1.2 && d > 2.2 {
                Some(-12.0 * (3.0 - d))
            } else {
                None
            }
        });
        let d = run(&r);
        assert_eq!(d.defects.len(), 1, "{:?}", d.defects);
        assert_eq!(d.defects[0].kind, DefectKind::Hole);
        assert!(
            d.candidates
                .iter()
                .any(|c| c.kind == DefectKind::Anomaly && !c.reported && c.defect.is_none()),
            "the wall was weighed as an anomaly and merged: {:?}",
            d.candidates
        );
    }

    #[test]
    fn a_golden_scans_wrong_index_fragments_are_not_held_against_the_part() {
        // The golden scan has a thin column of heights 3 mm low (one stripe coded one index off over 20 rows);
        // the part is clean. Uncleaned, the column would stand in the reference as a pit the part "fills".
        let part = plate(|_, _| Some(0.0));
        let mut golden = plate(|_, _| Some(0.0));
        for j in 80..100 {
            golden.z[j * golden.width + 120] -= 3.0;
        }
        let mut rules = SurfaceRules::shipped().expect("rules");
        let i = inspect(
            &part,
            ReferenceSource::Golden(&golden),
            &CharacterizeParams::default(),
            &mut rules,
            &DetectParams::default(),
        )
        .expect("inspect");
        assert!(i.detection.defects.is_empty(), "{:?}", i.detection.defects);
    }

    #[test]
    fn a_prepared_golden_scan_inspects_as_the_golden_scan_and_refuses_other_parameters() {
        // A part with a dent, against a golden scan with a wrong-index column (cleaned by the preparation as by the
        // inspection) and a 3 mm step (its walls' spans reach a travel step).
        let part = plate(|x, y| {
            Some(if x > 5.0 { 3.0 } else { 0.0 } - 0.3 * bell((x + 8.0).hypot(y - 2.0), 2.5))
        });
        let mut golden = plate(|x, _| Some(if x > 5.0 { 3.0 } else { 0.0 }));
        for j in 80..100 {
            golden.z[j * golden.width + 60] -= 3.0;
        }
        let params = DetectParams {
            travel_step_mm: Some(0.5),
            ..DetectParams::default()
        };
        let cp = CharacterizeParams::default();
        let mut rules = SurfaceRules::shipped().expect("rules");
        let raw = inspect(
            &part,
            ReferenceSource::Golden(&golden),
            &cp,
            &mut rules,
            &params,
        )
        .expect("inspect");
        let prepared = PreparedGolden::new(&golden, params.outlier_mm, cp.belt_level_mm, Some(0.5));
        let ready = inspect(
            &part,
            ReferenceSource::Prepared(&prepared),
            &cp,
            &mut rules,
            &params,
        )
        .expect("inspect");
        assert_eq!(
            raw.detection.defects.len(),
            1,
            "{:?}",
            raw.detection.defects
        );
        assert_eq!(raw.detection, ready.detection);
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert!(bits(&raw.maps.reference_mm) == bits(&ready.maps.reference_mm));
        // Prepared with another outlier limit or travel step: refused, naming it.
        for (other, what) in [
            (
                PreparedGolden::new(&golden, 2.0, cp.belt_level_mm, Some(0.5)),
                "outlier limit",
            ),
            (
                PreparedGolden::new(&golden, params.outlier_mm, cp.belt_level_mm, None),
                "travel step",
            ),
            (
                PreparedGolden::new(&golden, params.outlier_mm, 1.0, Some(0.5)),
                "belt level",
            ),
        ] {
            let e = inspect(
                &part,
                ReferenceSource::Prepared(&other),
                &cp,
                &mut rules,
                &params,
            )
            .expect_err("other parameters");
            assert!(e.to_string().contains(what), "{e}");
        }
    }

    #[test]
    fn a_piece_of_a_dent_is_not_a_second_dent() {
        // A 6 mm dent split by a column of cells 0.3 mm too high (a wrong-index column through it): the small
        // piece right of the column lies within the large piece's footprint.
        let r = plate(|x, y| {
            let d = x.hypot(y);
            let dent = -0.3 * bell(d, 3.0);
            if (x - 1.3).abs() < 0.15 && y.abs() < 3.5 {
                Some(dent + 0.3)
            } else {
                Some(dent)
            }
        });
        let d = run(&r);
        let dents: Vec<&Defect> = d
            .defects
            .iter()
            .filter(|e| e.kind == DefectKind::Dent)
            .collect();
        assert_eq!(dents.len(), 1, "{:?}", d.defects);
        assert!(dents[0].centroid_mm[0].abs() < 0.5, "{:?}", dents[0]);
    }

    #[test]
    fn a_channel_of_missing_data_does_not_unmake_a_hole() {
        // A 5 mm through-hole with a column of no data 0.6 mm wide running 8 mm from it (a stripe dropped for a
        // frame): the hole is still a hole, measured without the column.
        let r = plate(|x, y| {
            if x.hypot(y) < 2.5 || (x.abs() < 0.3 && y > 0.0 && y < 10.0) {
                None
            } else {
                Some(0.0)
            }
        });
        let d = run(&r);
        assert_eq!(d.defects.len(), 1, "{:?} {:?}", d.defects, d.unmeasured);
        let hole = &d.defects[0];
        assert_eq!(hole.kind, DefectKind::Hole);
        let area = std::f64::consts::PI * 2.5 * 2.5;
        assert!((hole.area_mm2 - area).abs() < 0.15 * area, "{hole:?}");
        assert!(
            hole.centroid_mm[0].hypot(hole.centroid_mm[1]) < 0.5,
            "{hole:?}"
        );
    }

    #[test]
    fn a_seam_of_missing_samples_at_the_surfaces_height_is_not_a_hole() {
        // Three columns of no data one cell wide, 0.4 mm apart, over 1.4 mm (a stripe dropped in every other frame):
        // the measured columns between them are too thin for the part's mask, so the gap holds the surface's own
        // heights (the rules alone call it a hole, with its bottom seen 0.0002 mm deep).
        let r = plate(|x, y| {
            let column = |c: f64| (x - c).abs() < 0.1;
            if (column(0.0) || column(0.4) || column(0.8)) && y > 0.0 && y < 1.4 {
                None
            } else {
                Some(0.0)
            }
        });
        let d = run(&r);
        assert!(d.defects.is_empty(), "{:?}", d.defects);
        assert!(
            d.unmeasured.iter().any(|u| u.reason.contains("not a hole")),
            "{:?}",
            d.unmeasured
        );
    }

    #[test]
    fn a_gap_narrower_than_the_sampling_is_unmeasured_and_a_2_mm_hole_is_a_hole() {
        // A patch without data 1.2 x 1.6 mm (a stripe's samples missing over three frames of 0.5 mm: 1.56 mm
        // equivalent diameter), and a 2 mm through-hole. With the travel step known, the patch is narrower than the
        // sampling can tell from missing samples, and the report says so; the rules alone call both holes.
        let r = plate(|x, y| {
            if (x + 8.0).abs() < 0.6 && (y - 2.0).abs() < 0.8 || (x - 8.0).hypot(y + 3.0) < 1.0 {
                None
            } else {
                Some(0.0)
            }
        });
        let maps = plane_maps(&r);
        let mut rules = SurfaceRules::shipped().expect("rules");
        let mut holes = |step: Option<f64>| {
            let params = DetectParams {
                travel_step_mm: step,
                ..DetectParams::default()
            };
            detect(&r, &maps, &mut rules, &params).expect("detect")
        };
        assert_eq!(holes(None).defects.len(), 2);
        let d = holes(Some(0.5));
        assert_eq!(d.defects.len(), 1, "{:?}", d.defects);
        let hole = &d.defects[0];
        assert_eq!(hole.kind, DefectKind::Hole);
        assert!((hole.centroid_mm[0] - 8.0).abs() < 0.3, "{hole:?}");
        let patch = d
            .unmeasured
            .iter()
            .find(|u| (u.centroid_mm[0] + 8.0).abs() < 0.5)
            .expect("the patch is reported as unmeasured");
        assert!(
            patch.reason.contains("too small to tell a hole"),
            "{}",
            patch.reason
        );
    }

    #[test]
    fn one_frames_misplaced_samples_are_unmeasured_and_a_2_mm_bump_is_a_bump() {
        // One frame's samples 0.3 mm low over 1.2 mm of rows, filled linearly to the frames 0.5 mm before and after
        // (a triangle one step wide at half its depth), and a bump 2 mm across, 0.2 mm high (1 mm wide there).
        let r = plate(|x, y| {
            let frame = if (y - 4.0).abs() < 0.6 {
                -0.3 * (1.0 - (x + 8.0).abs() / 0.5).max(0.0)
            } else {
                0.0
            };
            Some(frame + 0.2 * bell((x - 8.0).hypot(y + 3.0), 1.0))
        });
        let maps = plane_maps(&r);
        let mut rules = SurfaceRules::shipped().expect("rules");
        let mut found = |step: Option<f64>, steps: f64| {
            let params = DetectParams {
                travel_step_mm: step,
                min_region_travel_steps: steps,
                ..DetectParams::default()
            };
            detect(&r, &maps, &mut rules, &params).expect("detect")
        };
        let kinds = |d: &Detection| d.defects.iter().map(|d| d.kind).collect::<Vec<_>>();
        let without = found(None, 1.5);
        assert_eq!(kinds(&without), [DefectKind::Dent, DefectKind::Bump]);
        assert_eq!(
            kinds(&found(Some(0.5), 0.0)),
            [DefectKind::Dent, DefectKind::Bump]
        );
        let d = found(Some(0.5), 1.5);
        assert_eq!(kinds(&d), [DefectKind::Bump], "{:?}", d.unmeasured);
        assert!((d.defects[0].centroid_mm[0] - 8.0).abs() < 0.2);
        let spike = d
            .unmeasured
            .iter()
            .find(|u| (u.centroid_mm[0] + 8.0).abs() < 0.5)
            .expect("the frame's samples are reported as unmeasured");
        assert!(
            spike.reason.contains("one frame's misplaced samples"),
            "{}",
            spike.reason
        );
        assert_eq!(d.candidates.len() + 1, without.candidates.len());
    }

    #[test]
    fn clean_plate_has_no_defects() {
        let d = run(&plate(|_, _| Some(0.0)));
        assert!(d.defects.is_empty(), "{:?}", d.defects);
        assert!(d.warnings.is_empty(), "{:?}", d.warnings);
        assert!(d.coverage > 0.99);
    }

    #[test]
    fn the_normal_quantile_matches_its_tables() {
        for (p, z) in [
            (0.5, 0.0),
            (0.975, 1.959_964),
            (0.8413447, 1.0),
            (0.999, 3.090_232),
            (1.0 - 1e-6, 4.753_424),
            (1e-6, -4.753_424),
            (0.025, -1.959_964),
        ] {
            assert!(
                (normal_quantile(p) - z).abs() < 1e-5,
                "{p}: {}",
                normal_quantile(p)
            );
        }
        assert_eq!(normal_quantile(0.0), f64::NEG_INFINITY);
        assert_eq!(normal_quantile(1.0), f64::INFINITY);
    }

    #[test]
    fn a_noisy_scan_raises_its_threshold_and_says_what_it_can_see() {
        // 1 mm cells of the top each off by up to ±0.07 mm (the way a printed pattern bends frame centres), and one
        // dent 0.5 mm deep.
        let r = plate(|x, y| {
            let cell =
                ((x + 100.0).floor() as i64 * 7919 + (y + 100.0).floor() as i64 * 104_729) % 1000;
            let offset = (cell as f64 / 1000.0 - 0.5) * 0.14;
            let dent = 0.5 * bell(x.hypot(y - 2.0), 3.0);
            Some(offset - dent)
        });
        let mut rules = SurfaceRules::shipped().expect("rules");
        let maps = plane_maps(&r);
        let fixed = DetectParams {
            false_alarm: 0.0,
            ..DetectParams::default()
        };
        let blind = detect(&r, &maps, &mut rules, &fixed).expect("detect");
        assert!(blind.defects.len() > 5, "{:?}", blind.defects.len());
        let d = detect(&r, &maps, &mut rules, &DetectParams::default()).expect("detect");
        assert!(d.detectable.raised, "{:?}", d.detectable);
        assert!(d.detectable.threshold_mm > 0.1, "{:?}", d.detectable);
        assert!(
            d.warnings.iter().any(|w| w.contains("cannot be seen")),
            "{:?}",
            d.warnings
        );
        assert_eq!(d.defects.len(), 1, "{:?}", d.defects);
        assert_eq!(d.defects[0].kind, DefectKind::Dent);
        // A clean plate keeps the method's threshold.
        let clean = run(&plate(|_, _| Some(0.0)));
        assert!(!clean.detectable.raised, "{:?}", clean.detectable);
        assert_eq!(
            clean.detectable.threshold_mm,
            DetectParams::default().seed_mm
        );
        assert!(clean.detectable.noise_mm > 0.0 && clean.detectable.noise_mm < 0.005);
    }

    #[test]
    fn bump_dent_hole_scratch_and_chip_are_found_measured_and_named() {
        let r = plate(|x, y| {
            let bump = 0.3 * bell((x + 10.0).hypot(y - 5.0), 2.5);
            let dent = -0.15 * bell((x - 8.0).hypot(y + 6.0), 1.5);
            let scratch = if (y - 8.0).abs() < 0.3 && x > 2.0 && x < 14.0 {
                -0.2
            } else {
                0.0
            };
            if (x - 0.0).hypot(y + 2.0) < 1.5 || (x - 20.0).hypot(y) < 2.0 {
                None
            } else {
                Some(bump + dent + scratch)
            }
        });
        // The chip is cut through the plate down to the belt.
        let mut r = r;
        for j in 0..r.height {
            for i in 0..r.width {
                let (x, y) = cell_xy(&r, i, j);
                if (x - 20.0).hypot(y) < 2.0 && x <= 20.0 {
                    r.z[j * r.width + i] = 0.0;
                }
            }
        }
        let d = run(&r);
        let find = |k: DefectKind| {
            d.defects
                .iter()
                .find(|x| x.kind == k)
                .unwrap_or_else(|| panic!("no {k:?} in {:#?}", d.defects))
        };
        let b = find(DefectKind::Bump);
        assert!(
            (b.centroid_mm[0] + 10.0).abs() < 0.1 && (b.centroid_mm[1] - 5.0).abs() < 0.1,
            "{b:?}"
        );
        assert!((b.depth_mm - 0.3).abs() < 0.02, "{b:?}");
        let area = std::f64::consts::PI * 2.5 * 2.5;
        assert!((b.area_mm2 - area).abs() < 0.1 * area, "{b:?}");
        let dent = find(DefectKind::Dent);
        assert!(
            (dent.depth_mm - 0.15).abs() < 0.02 && (dent.centroid_mm[0] - 8.0).abs() < 0.1,
            "{dent:?}"
        );
        let hole = find(DefectKind::Hole);
        assert!(
            (hole.depth_mm - 10.0).abs() < 0.05 && !hole.bottom_seen,
            "{hole:?}"
        );
        assert!(
            (hole.area_mm2 - std::f64::consts::PI * 2.25).abs() < 0.2 * 7.07,
            "{hole:?}"
        );
        let s = find(DefectKind::Scratch);
        assert!(s.bbox_mm[2] - s.bbox_mm[0] > 10.0, "{s:?}");
        let c = find(DefectKind::EdgeChip);
        assert!((c.centroid_mm[0] - 19.2).abs() < 0.5, "{c:?}");
        assert_eq!(d.defects.len(), 5, "{:#?}", d.defects);
    }

    #[test]
    fn empty_scans_and_parts_out_of_view_are_reported() {
        let empty = RangeImage {
            origin_mm: [0.0, 0.0],
            spacing_mm: [0.2, 0.2],
            width: 10,
            height: 10,
            z: vec![f32::NAN; 100],
            intensity: None,
        };
        let p = CharacterizeParams::default();
        assert!(fit_reference(&empty, &p).is_err());
        let maps = surface_maps(&empty, vec![0.0; 100], &p).expect("maps");
        let mut rules = SurfaceRules::shipped().expect("rules");
        let e = detect(&empty, &maps, &mut rules, &DetectParams::default()).expect_err("no part");
        assert!(e.to_string().contains("no part"), "{e}");
        // A plate running off the top of the grid.
        let mut r = plate(|_, _| Some(0.0));
        for i in 0..r.width {
            let (x, _) = cell_xy(&r, i, 0);
            if x.abs() < 20.0 {
                for j in 0..30 {
                    r.z[j * r.width + i] = 10.0;
                }
            }
        }
        let d = run(&r);
        assert!(
            d.warnings.iter().any(|w| w.contains("top")),
            "{:?}",
            d.warnings
        );
    }

    /// Naive dilation (grow) or erosion over a (2r+1)² window clipped to the grid.
    fn naive(w: usize, h: usize, m: &[bool], r: usize, grow: bool) -> Vec<bool> {
        (0..w * h)
            .map(|k| {
                let (i, j) = (k % w, k / w);
                let hit = (j.saturating_sub(r)..(j + r + 1).min(h)).any(|jj| {
                    (i.saturating_sub(r)..(i + r + 1).min(w)).any(|ii| m[jj * w + ii] == grow)
                });
                if hit { grow } else { !grow }
            })
            .collect()
    }

    proptest::proptest! {
        #[test]
        fn separable_morphology_matches_the_naive_window(
            w in 1usize..140, h in 1usize..8, r in 1usize..4, grow: bool, bits in proptest::collection::vec(proptest::bool::ANY, 1120)
        ) {
            let m = &bits[..w * h];
            proptest::prop_assert_eq!(morph(w, h, m, r, grow), naive(w, h, m, r, grow));
            // Closing and opening are the two compositions.
            proptest::prop_assert_eq!(
                closing(w, h, m, r),
                naive(w, h, &naive(w, h, m, r, true), r, false)
            );
            proptest::prop_assert_eq!(opening(w, h, m), naive(w, h, &naive(w, h, m, 1, false), 1, true));
        }

        #[test]
        fn chamfer_distance_is_within_8_percent_of_euclidean(
            w in 2usize..15, h in 2usize..15, seeds in proptest::collection::vec((0usize..15, 0usize..15), 1..4)
        ) {
            let pts: Vec<(usize, usize)> = seeds.iter().map(|&(i, j)| (i % w, j % h)).collect();
            let d = distance_to(w, h, |k| pts.contains(&(k % w, k / w)));
            for (k, &dk) in d.iter().enumerate() {
                let (i, j) = ((k % w) as f64, (k / w) as f64);
                let e = pts.iter().map(|&(a, b)| (i - a as f64).hypot(j - b as f64)).fold(f64::INFINITY, f64::min);
                proptest::prop_assert!((f64::from(dk) - e).abs() <= 0.09 * e + 1e-6, "{dk} vs {e}");
            }
        }
    }

    #[test]
    fn kinds_round_trip_by_name() {
        for k in DefectKind::ALL {
            assert_eq!(DefectKind::from_name(k.name()), Some(k));
        }
    }
}
