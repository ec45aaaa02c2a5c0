//! Learning from operators' feedback.
//!
//! Two things are learned, both written into a *new* knowledge-base version (never over the old one):
//! - **Cause priors**: each cause's prior becomes the Bayesian mean of its knowledge-file prior (worth
//!   [`PRIOR_WEIGHT`] observations) and the share of operator-confirmed causes among its process's defects:
//!   `(prior · w + confirmed_c) / (w + confirmed_total)`; the counts go to `statistics.toml`.
//! - **Fuzzy classification parameters**: the numeric parameters of the input terms of the surface rule base
//!   (SShape, ZShape, Ramp, Triangle, Trapezoid breakpoints) are tuned by a gradient-free pattern search
//!   (Hooke-Jeeves with step halving) that maximises the defect F1 on the labelled history. Each stored candidate
//!   (every region the rules weighed, reported or not) is re-decided with [`stripe3d_core::detect::decide`] — the
//!   very decision detection takes — so a tuned rule base changes exactly what the next inspection reports. A
//!   step is kept only when it raises the F1 strictly; parameters stay ordered and inside their variable's range.

use crate::KbError;
use crate::model::KnowledgeBase;
use std::collections::BTreeMap;
use stripe3d_core::detect::{
    CandidateSource, DefectKind, DetectParams, Evidence, SurfaceRules, decide,
};
use stripe3d_fuzzy::Engine;
use stripe3d_fuzzy::term::Shape;

/// How many observations a knowledge-file prior is worth when confirmed causes update it.
pub const PRIOR_WEIGHT: f64 = 10.0;
/// Most F1 evaluations of one tuning run.
pub const MAX_EVALUATIONS: usize = 4000;

/// One candidate with the operator's judgement.
#[derive(Debug, Clone, PartialEq)]
pub struct Labelled {
    /// Which test found it.
    pub source: CandidateSource,
    /// What the rules were told.
    pub evidence: Evidence,
    /// Area, mm².
    pub area_mm2: f64,
    /// What it really is (None: not a defect).
    pub truth: Option<DefectKind>,
}

/// A judgement at a place: an operator's (confirmed, false alarm, missed) or the simulator's truth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mark {
    /// What is there (None: nothing, a false alarm).
    pub kind: Option<DefectKind>,
    /// Where, part coordinates, mm.
    pub at_mm: [f64; 2],
    /// How far from it a candidate's centre may lie, mm.
    pub radius_mm: f64,
}

/// Labels a reviewed part's candidates from marks: each candidate takes the nearest mark within the mark's radius;
/// a candidate no mark reaches is not a defect. Returns the labelled candidates and the number of marked defects
/// no candidate reaches (defects the detection never saw: they count as misses whatever the rules).
pub fn label_by_position(
    candidates: &[stripe3d_core::detect::Candidate],
    marks: &[Mark],
) -> (Vec<Labelled>, usize) {
    let mut used = vec![false; marks.len()];
    let labelled = candidates
        .iter()
        .map(|c| {
            let near = marks
                .iter()
                .enumerate()
                .map(|(k, m)| {
                    (
                        k,
                        (m.at_mm[0] - c.centroid_mm[0]).hypot(m.at_mm[1] - c.centroid_mm[1]),
                    )
                })
                .filter(|(k, d)| *d <= marks[*k].radius_mm)
                .min_by(|a, b| a.1.total_cmp(&b.1));
            let truth = near.and_then(|(k, _)| {
                used[k] = true;
                marks[k].kind
            });
            Labelled {
                source: c.source,
                evidence: c.evidence,
                area_mm2: c.area_mm2,
                truth,
            }
        })
        .collect();
    let missed = marks
        .iter()
        .zip(&used)
        .filter(|(m, u)| m.kind.is_some() && !**u)
        .count();
    (labelled, missed)
}

/// Defect-level scores.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Score {
    /// Reported with the right kind.
    pub true_positive: usize,
    /// Reported but not a defect, or of the wrong kind.
    pub false_positive: usize,
    /// Real defects not reported with their kind.
    pub false_negative: usize,
}

impl Score {
    /// F1 = 2 TP / (2 TP + FP + FN); 0 when nothing is right.
    pub fn f1(&self) -> f64 {
        if self.true_positive == 0 {
            0.0
        } else {
            2.0 * self.true_positive as f64
                / (2 * self.true_positive + self.false_positive + self.false_negative) as f64
        }
    }
}

/// Scores `rules` on `data`; `missed` real defects had no candidate at all (they count as false negatives).
pub fn score(
    rules: &mut SurfaceRules,
    params: &DetectParams,
    data: &[Labelled],
    missed: usize,
) -> Result<Score, KbError> {
    let mut s = Score {
        false_negative: missed,
        ..Score::default()
    };
    for c in data {
        let (kind, _, reported) = decide(c.source, &c.evidence, c.area_mm2, rules, params)
            .map_err(|e| KbError::Learning(e.to_string()))?;
        match (reported, c.truth) {
            (true, Some(t)) if t == kind => s.true_positive += 1,
            (true, Some(_)) => {
                s.false_positive += 1;
                s.false_negative += 1;
            }
            (true, None) => s.false_positive += 1,
            (false, Some(_)) => s.false_negative += 1,
            (false, None) => {}
        }
    }
    Ok(s)
}

/// One tuned parameter: where it lives and its value before and after.
#[derive(Debug, Clone, PartialEq)]
pub struct ParameterChange {
    /// `variable.term`.
    pub term: String,
    /// Index of the parameter within the term.
    pub index: usize,
    /// Before.
    pub before: f64,
    /// After.
    pub after: f64,
}

/// What a tuning run did.
#[derive(Debug, Clone, PartialEq)]
pub struct TuneReport {
    /// Score with the rules as they were.
    pub before: Score,
    /// Score with the tuned rules.
    pub after: Score,
    /// Parameters that moved.
    pub changes: Vec<ParameterChange>,
    /// F1 evaluations spent.
    pub evaluations: usize,
}

/// The tunable parameters of a term (breakpoints only; heights stay).
fn params_of(shape: &Shape) -> Vec<f64> {
    match *shape {
        Shape::SShape { start, end, .. }
        | Shape::ZShape { start, end, .. }
        | Shape::Ramp { start, end, .. } => vec![start, end],
        Shape::Triangle { a, b, c, .. } => vec![a, b, c],
        Shape::Trapezoid { a, b, c, d, .. } => vec![a, b, c, d],
        _ => vec![],
    }
}

fn set_params(shape: &mut Shape, v: &[f64]) {
    match shape {
        Shape::SShape { start, end, .. }
        | Shape::ZShape { start, end, .. }
        | Shape::Ramp { start, end, .. } => {
            *start = v[0];
            *end = v[1];
        }
        Shape::Triangle { a, b, c, .. } => {
            *a = v[0];
            *b = v[1];
            *c = v[2];
        }
        Shape::Trapezoid { a, b, c, d, .. } => {
            *a = v[0];
            *b = v[1];
            *c = v[2];
            *d = v[3];
        }
        _ => {}
    }
}

/// (input, term, parameter count) of every tunable term.
fn tunable(engine: &Engine) -> Vec<(usize, usize, usize)> {
    let mut out = Vec::new();
    for (i, v) in engine.inputs.iter().enumerate() {
        for (t, term) in v.terms.iter().enumerate() {
            let n = params_of(&term.shape).len();
            if n > 0 {
                out.push((i, t, n));
            }
        }
    }
    out
}

fn apply(engine: &mut Engine, layout: &[(usize, usize, usize)], x: &[f64]) {
    let mut k = 0;
    for &(i, t, n) in layout {
        set_params(&mut engine.inputs[i].terms[t].shape, &x[k..k + n]);
        k += n;
    }
}

/// Tunes the input terms of `rules` on `data` (see the module docs). Returns the tuned engine and the report.
pub fn tune_rules(
    rules: &SurfaceRules,
    params: &DetectParams,
    data: &[Labelled],
    missed: usize,
) -> Result<(Engine, TuneReport), KbError> {
    let base = rules.engine().clone();
    let layout = tunable(&base);
    let mut x: Vec<f64> = layout
        .iter()
        .flat_map(|&(i, t, _)| params_of(&base.inputs[i].terms[t].shape))
        .collect();
    let x0 = x.clone();
    // Per parameter: its variable's range (steps start at a tenth of the term's span or of the range).
    let mut bounds = Vec::new();
    let mut steps = Vec::new();
    for &(i, t, n) in &layout {
        let v = &base.inputs[i];
        let p = params_of(&v.terms[t].shape);
        let span = (p[n - 1] - p[0]).abs();
        let range = if v.maximum.is_finite() && v.minimum.is_finite() {
            v.maximum - v.minimum
        } else {
            span.max(1.0) * 10.0
        };
        for _ in 0..n {
            bounds.push((v.minimum, v.maximum));
            steps.push((0.25 * span).max(0.01 * range));
        }
    }
    let evaluations = std::cell::Cell::new(0usize);
    let eval = |x: &[f64]| -> Result<Score, KbError> {
        evaluations.set(evaluations.get() + 1);
        let mut e = base.clone();
        apply(&mut e, &layout, x);
        e.load().map_err(|e| KbError::Learning(e.to_string()))?;
        let mut r = SurfaceRules::from_engine(e).map_err(|e| KbError::Learning(e.to_string()))?;
        score(&mut r, params, data, missed)
    };
    let before = eval(&x)?;
    let mut best = before;
    // Valid: finite, inside the range, ordered within each term.
    let valid = |x: &[f64]| -> bool {
        let mut k = 0;
        for &(_, _, n) in &layout {
            let p = &x[k..k + n];
            if p.windows(2).any(|w| w[0] > w[1]) {
                return false;
            }
            k += n;
        }
        x.iter()
            .zip(&bounds)
            .all(|(v, (lo, hi))| v.is_finite() && *v >= *lo && *v <= *hi)
    };
    let min_step: Vec<f64> = steps.iter().map(|s| s / 64.0).collect();
    while steps.iter().zip(&min_step).any(|(s, m)| s > m) && evaluations.get() < MAX_EVALUATIONS {
        let mut improved = false;
        for k in 0..x.len() {
            if steps[k] <= min_step[k] {
                continue;
            }
            for dir in [1.0, -1.0] {
                let mut y = x.clone();
                y[k] += dir * steps[k];
                if !valid(&y) {
                    continue;
                }
                let s = eval(&y)?;
                if s.f1() > best.f1() + 1e-12 {
                    best = s;
                    x = y;
                    improved = true;
                    break;
                }
            }
        }
        if !improved {
            for s in &mut steps {
                *s /= 2.0;
            }
        }
    }
    let mut tuned = base.clone();
    apply(&mut tuned, &layout, &x);
    tuned.load().map_err(|e| KbError::Learning(e.to_string()))?;
    let mut changes = Vec::new();
    let mut k = 0;
    for &(i, t, n) in &layout {
        for j in 0..n {
            if (x[k + j] - x0[k + j]).abs() > 1e-12 {
                changes.push(ParameterChange {
                    term: format!("{}.{}", base.inputs[i].name, base.inputs[i].terms[t].name),
                    index: j,
                    before: x0[k + j],
                    after: x[k + j],
                });
            }
        }
        k += n;
    }
    Ok((
        tuned,
        TuneReport {
            before,
            after: best,
            changes,
            evaluations: evaluations.get(),
        },
    ))
}

/// Updates the cause priors of `kb`'s processes from confirmed causes (`counts[product][cause]`) and records the
/// statistics; returns readable lines of what changed.
pub fn update_priors(
    kb: &mut KnowledgeBase,
    confirmed: &BTreeMap<String, BTreeMap<String, u64>>,
) -> Vec<String> {
    let mut lines = Vec::new();
    // Sum confirmations per process over the products it makes.
    let mut per_process: BTreeMap<String, BTreeMap<String, u64>> = BTreeMap::new();
    for (product, causes) in confirmed {
        if let Some(p) = kb.products.get(product) {
            let e = per_process.entry(p.process.clone()).or_default();
            for (c, n) in causes {
                *e.entry(c.clone()).or_default() += n;
            }
        }
    }
    for (process, counts) in per_process {
        let total: u64 = counts.values().sum();
        if total == 0 {
            continue;
        }
        if let Some(p) = kb.processes.get_mut(&process) {
            for name in counts.keys() {
                if !p.causes.iter().any(|c| &c.name == name) {
                    lines.push(format!(
                        "process `{process}` has no cause `{name}` (named in {} feedback entries): not counted; add \
                         it to processes/{process}.toml if it is real",
                        counts[name]
                    ));
                }
            }
            let known: u64 = counts
                .iter()
                .filter(|(n, _)| p.causes.iter().any(|c| &c.name == *n))
                .map(|(_, v)| v)
                .sum();
            if known == 0 {
                continue;
            }
            let total = known;
            for c in &mut p.causes {
                let n = counts.get(&c.name).copied().unwrap_or(0) as f64;
                let new =
                    ((c.prior * PRIOR_WEIGHT + n) / (PRIOR_WEIGHT + total as f64)).clamp(0.01, 1.0);
                if (new - c.prior).abs() > 1e-9 {
                    lines.push(format!(
                        "process `{process}` cause `{}`: prior {:.3} -> {new:.3} ({n} of {total} confirmed causes)",
                        c.name, c.prior
                    ));
                    c.prior = (new * 1000.0).round() / 1000.0;
                }
            }
        }
    }
    lines
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ev(elongation: f64, direction: f64) -> Evidence {
        Evidence {
            curvature_per_mm: 0.3,
            direction,
            gap_mm: 0.0,
            height_similarity_mm: 50.0,
            elongation,
            edge_notch_mm: 0.0,
            cells: 500,
        }
    }

    #[test]
    fn confirmed_causes_move_the_priors_and_unknown_ones_are_named() {
        let mut kb = crate::shipped().expect("kb");
        let mut counts = BTreeMap::new();
        counts.insert(
            "cover-plate".to_string(),
            BTreeMap::from([
                ("die-debris".to_string(), 10u64),
                ("gremlins".to_string(), 3),
            ]),
        );
        let lines = update_priors(&mut kb, &counts);
        let stamping = &kb.processes["stamping"];
        let prior = |n: &str| {
            stamping
                .causes
                .iter()
                .find(|c| c.name == n)
                .map(|c| c.prior)
        };
        // (0.3 * 10 + 10) / (10 + 10) = 0.65; the others shrink: (0.3 * 10 + 0) / 20 = 0.15.
        assert_eq!(prior("die-debris"), Some(0.65));
        assert_eq!(prior("handling-damage"), Some(0.15));
        assert!(
            lines
                .iter()
                .any(|l| l.contains("gremlins") && l.contains("not counted")),
            "{lines:?}"
        );
        assert!(kb.validate().is_ok());
    }

    #[test]
    fn tuning_moves_the_long_term_to_separate_short_scratches_from_dents() {
        let rules = SurfaceRules::shipped().expect("rules");
        let params = DetectParams::default();
        let mut data = Vec::new();
        for k in 0..20 {
            let t = k as f64 / 20.0;
            data.push(Labelled {
                source: CandidateSource::Surface,
                evidence: ev(1.0 + 0.8 * t, -1.0),
                area_mm2: 10.0,
                truth: Some(DefectKind::Dent),
            });
            data.push(Labelled {
                source: CandidateSource::Surface,
                evidence: ev(3.0 + 1.5 * t, -1.0),
                area_mm2: 3.0,
                truth: Some(DefectKind::Scratch),
            });
        }
        let (engine, report) = tune_rules(&rules, &params, &data, 0).expect("tune");
        assert!(
            report.before.f1() < 0.8,
            "shipped rules call short scratches dents: {:?}",
            report.before
        );
        assert!(report.after.f1() > 0.99, "tuned: {:?}", report.after);
        assert!(report.changes.iter().any(|c| c.term == "elongation.long"));
        // The tuned engine decides as the report says.
        let mut tuned = SurfaceRules::from_engine(engine).expect("tuned rules");
        assert_eq!(
            score(&mut tuned, &params, &data, 0).expect("score"),
            report.after
        );
        // Nothing to learn from: nothing changes.
        let (_, same) = tune_rules(&rules, &params, &data[..2], 0).expect("tune");
        assert!(same.changes.is_empty());
    }
}
