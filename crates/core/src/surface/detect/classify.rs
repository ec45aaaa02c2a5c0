//! Candidates' evidence weighed by the surface rule base into a kind and a confidence.

use super::*;

/// The surface rule base, ready to evaluate.
#[derive(Debug, Clone)]
pub struct SurfaceRules {
    engine: Engine,
    inputs: [usize; 6],
    outputs: [(usize, DefectKind); 5],
}

pub(super) fn rule_error(e: impl ToString) -> CoreError {
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
pub(super) fn below_sampling(evidence: &Evidence, params: &DetectParams) -> bool {
    params
        .travel_step_mm
        .is_some_and(|step| evidence.gap_mm < params.min_hole_travel_steps * step)
}

/// The region's widest extent along x (the conveyor's travel) within one row, over its cells at least half its peak
/// deviation, mm: a single frame's misplaced samples deviate over about one travel step (the fill between the
/// frames before and after), a bump or dent of diameter D over about D / 2 (a raised cosine's width at half its
/// height).
pub(super) fn half_peak_travel_width(
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
pub(super) fn weigh(
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
