//! Reasoning: measured defects + product + process + method → verdict, ranked diagnosis, and a trace a quality
//! engineer can read.
//!
//! The engine is small on purpose (the rules are data in the knowledge files, evaluated in one pass; no chaining is
//! needed because no rule's conclusion is another rule's premise):
//! 1. *Designed features*: a detected hole within max(1 mm, d/4) of a designed hole is that hole, not a defect
//!    (its diameter checked against the feature's tolerance); a designed hole with no gap where a fitted reference
//!    expects one is missing.
//! 2. *Standards*: each defect is compared with its zone's limits and the method's standards; the worst decision
//!    wins. Tolerances of the whole part (thickness, flatness) are compared where the measurement exists.
//! 3. *Diagnosis*: for each defect, each cause of the product's process that produces its kind starts at its prior
//!    and combines the certainty factors of the evidence rules that fire (MYCIN's combination: two positives
//!    `a + b (1 − a)`, two negatives `a + b (1 + a)`, mixed `(a + b) / (1 − min(|a|, |b|))`), so numeric
//!    measurements (size, distance to the edge, recurrence across parts) sharpen the symbolic knowledge ("die
//!    debris makes dents"). A part's certainty for a cause is the largest over its defects; a batch's is the mean
//!    over its parts.
//!
//! A rule or datalog crate (crepe, datafrog, ascent) compiles its rules into the program; ours are loaded at run
//! time from the knowledge files, and certainty factors are not part of their semantics, so this engine is kept
//! small and documented here instead.

use crate::KbError;
use crate::model::{
    Decision, FeatureKind, KnowledgeBase, Measure, Method, Process, Product, ReferenceKind,
};
use serde::Serialize;
use stripe3d_core::accumulate::RangeImage;
use stripe3d_core::characterize::{
    CellClass, CharacterizeParams, ReferenceInfo, ReferenceShape, ReferenceSource, cell_xy,
};
use stripe3d_core::detect::{Defect, DefectKind, Detection, Inspection, SurfaceRules, inspect};
use stripe3d_core::{CoreError, InspectionError};

/// Distance (mm) within which a defect on another part counts as recurring at the same place.
pub const RECURRENCE_RADIUS_MM: f64 = 2.0;

/// One past part's defects: kind and product-frame centre (mm), for [`recurrence`].
pub type PartDefects = Vec<(DefectKind, [f64; 2])>;

/// Causes less certain than this are not named in a diagnosis.
pub const MIN_CERTAINTY: f64 = 0.05;

/// What is known about the part beyond its defects.
#[derive(Debug, Clone, Default)]
pub struct PartFacts {
    /// Thickness measured by a fitted reference at the part's centre, mm.
    pub thickness_mm: Option<f64>,
    /// Peak-to-valley flatness of the top surface about the fitted plane, mm.
    pub flatness_mm: Option<f64>,
    /// Per defect of the detection: share of the product's recent parts with a defect of its kind nearby (see
    /// [`recurrence`]); empty means no history.
    pub recurrence: Vec<f64>,
    /// The reference came from a fit (designed holes show as gaps) rather than a golden scan.
    pub fitted_reference: bool,
}

/// One cause with its certainty.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CauseCertainty {
    /// Cause name.
    pub cause: String,
    /// Process it belongs to.
    pub process: String,
    /// Certainty factor, 0 to 1.
    pub certainty: f64,
    /// What to do.
    pub remedy: String,
}

/// The reasoning's view of one detected defect.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AssessedDefect {
    /// Index into the detection's defects.
    pub index: usize,
    /// Kind.
    pub kind: String,
    /// Centre in the product frame, mm.
    pub product_xy_mm: [f64; 2],
    /// Zone it lies in.
    pub zone: Option<String>,
    /// What it leads to.
    pub decision: Decision,
    /// Why.
    pub reasons: Vec<String>,
    /// Ranked probable causes.
    pub causes: Vec<CauseCertainty>,
}

/// A designed feature and what the scan showed of it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FeatureCheck {
    /// Feature name.
    pub name: String,
    /// `found`, `missing`, `out-of-tolerance`, or `not-checked` (golden reference, bosses).
    pub status: String,
    /// Measured equivalent diameter, mm.
    pub measured_diameter_mm: Option<f64>,
    /// Index of the detected hole it explains.
    pub defect_index: Option<usize>,
}

/// The outcome of reasoning about one part.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Assessment {
    /// Product.
    pub product: String,
    /// The verdict.
    pub decision: Decision,
    /// Defects that are real defects (designed features removed), assessed.
    pub defects: Vec<AssessedDefect>,
    /// Designed features.
    pub features: Vec<FeatureCheck>,
    /// Ranked probable causes for the part.
    pub diagnosis: Vec<CauseCertainty>,
    /// Readable lines: why this verdict.
    pub trace: Vec<String>,
    /// Centre of the part's outline in part coordinates (the product frame's origin), mm.
    pub frame_origin_mm: [f64; 2],
}

/// MYCIN's combination of two certainty factors.
pub fn combine(a: f64, b: f64) -> f64 {
    if a >= 0.0 && b >= 0.0 {
        a + b * (1.0 - a)
    } else if a <= 0.0 && b <= 0.0 {
        a + b * (1.0 + a)
    } else {
        (a + b) / (1.0 - a.abs().min(b.abs())).max(1e-12)
    }
}

/// Share of `history` (each part: its defects' kinds and product-frame centres) with a defect of `kind` within
/// [`RECURRENCE_RADIUS_MM`] of `at`; 0 without history.
pub fn recurrence(history: &[PartDefects], kind: DefectKind, at: [f64; 2]) -> f64 {
    if history.is_empty() {
        return 0.0;
    }
    let hits = history
        .iter()
        .filter(|part| {
            part.iter().any(|(k, p)| {
                *k == kind && (p[0] - at[0]).hypot(p[1] - at[1]) <= RECURRENCE_RADIUS_MM
            })
        })
        .count();
    hits as f64 / history.len() as f64
}

/// The product frame's origin: the centre of the part's measured outline.
pub fn frame_origin(d: &Detection) -> [f64; 2] {
    let b = d.part_bbox_mm;
    if b.iter().all(|v| v.is_finite()) {
        [(b[0] + b[2]) / 2.0, (b[1] + b[3]) / 2.0]
    } else {
        [0.0, 0.0]
    }
}

/// Value of `m` for defect `d` (product-frame centre `p`) on a part of `product` with `count` defects of its kind.
fn measure(m: Measure, d: &Defect, p: [f64; 2], product: &Product, count: usize, rec: f64) -> f64 {
    let g = &product.geometry;
    match m {
        Measure::DiameterMm => 2.0 * (d.area_mm2 / std::f64::consts::PI).sqrt(),
        Measure::DepthMm => d.depth_mm,
        Measure::AreaMm2 => d.area_mm2,
        Measure::VolumeMm3 => d.volume_mm3,
        Measure::Elongation => d.evidence.elongation,
        Measure::EdgeDistanceMm => (g.length_mm / 2.0 - p[0].abs())
            .min(g.width_mm / 2.0 - p[1].abs())
            .max(0.0),
        Measure::Count => count as f64,
        Measure::Recurrence => rec,
        Measure::Confidence => d.confidence,
    }
}

fn fmt(v: f64) -> String {
    if v.abs() >= 100.0 {
        format!("{v:.0}")
    } else if v.abs() >= 1.0 {
        format!("{v:.2}")
    } else {
        format!("{v:.3}")
    }
}

fn unit(m: Measure) -> &'static str {
    match m {
        Measure::DiameterMm | Measure::DepthMm | Measure::EdgeDistanceMm => " mm",
        Measure::AreaMm2 => " mm²",
        Measure::VolumeMm3 => " mm³",
        _ => "",
    }
}

/// Certainty of each cause of `process` for one defect, with the trace of the evidence that fired.
fn causes_for(
    process: &Process,
    d: &Defect,
    value: impl Fn(Measure) -> f64,
) -> Vec<(CauseCertainty, String)> {
    let mut out = Vec::new();
    for c in &process.causes {
        if !c.kinds.iter().any(|k| k == d.kind.name()) {
            continue;
        }
        let mut cf = c.prior;
        let mut why = vec![format!("prior {}", fmt(c.prior))];
        for e in &c.evidence {
            let v = value(e.measure);
            if e.fires(v) {
                cf = combine(cf, e.cf);
                let bound = match (e.at_least, e.at_most) {
                    (Some(a), Some(b)) => format!("in [{}, {}]", fmt(a), fmt(b)),
                    (Some(a), None) => format!(">= {}", fmt(a)),
                    (None, Some(b)) => format!("<= {}", fmt(b)),
                    (None, None) => String::new(),
                };
                why.push(format!(
                    "{} {}{} {bound}: {:+.2}",
                    e.measure.name(),
                    fmt(v),
                    unit(e.measure),
                    e.cf
                ));
            }
        }
        out.push((
            CauseCertainty {
                cause: c.name.clone(),
                process: process.name.clone(),
                certainty: cf.clamp(0.0, 1.0),
                remedy: c.remedy.clone(),
            },
            why.join("; "),
        ));
    }
    out.sort_by(|a, b| b.0.certainty.total_cmp(&a.0.certainty));
    out
}

/// Reasons about one inspected part of `product_name`.
pub fn assess(
    kb: &KnowledgeBase,
    product_name: &str,
    detection: &Detection,
    facts: &PartFacts,
) -> Result<Assessment, KbError> {
    let (product, process, method) = kb.product_context(product_name)?;
    let origin = frame_origin(detection);
    let mut trace = Vec::new();
    let mut decision = Decision::Accept;
    let raise = |to: Decision, decision: &mut Decision| {
        if to > *decision {
            *decision = to;
        }
    };
    let to_product = |c: [f64; 2]| [c[0] - origin[0], c[1] - origin[1]];
    // 1. Designed features.
    let mut designed_of = vec![None; detection.defects.len()];
    let mut features = Vec::new();
    for f in &product.features {
        let mut check = FeatureCheck {
            name: f.name.clone(),
            status: "not-checked".into(),
            measured_diameter_mm: None,
            defect_index: None,
        };
        if f.kind == FeatureKind::Hole {
            let radius = (f.diameter_mm / 4.0).max(1.0);
            let hit = detection
                .defects
                .iter()
                .enumerate()
                .filter(|(i, d)| d.kind == DefectKind::Hole && designed_of[*i].is_none())
                .map(|(i, d)| {
                    let p = to_product(d.centroid_mm);
                    (i, (p[0] - f.x_mm).hypot(p[1] - f.y_mm), d)
                })
                .filter(|(_, dist, _)| *dist <= radius)
                .min_by(|a, b| a.1.total_cmp(&b.1));
            if let Some((i, _, d)) = hit {
                designed_of[i] = Some(f.name.clone());
                let dia = 2.0 * (d.area_mm2 / std::f64::consts::PI).sqrt();
                check.measured_diameter_mm = Some(dia);
                check.defect_index = Some(i);
                check.status = "found".into();
                if let Some(tol) = f.diameter_tolerance_mm {
                    if (dia - f.diameter_mm).abs() > tol {
                        check.status = "out-of-tolerance".into();
                        raise(Decision::Reject, &mut decision);
                        trace.push(format!(
                            "reject: designed hole `{}` measures {dia:.2} mm across, nominal {} ± {} mm",
                            f.name,
                            fmt(f.diameter_mm),
                            fmt(tol)
                        ));
                    }
                }
            } else if facts.fitted_reference && method.surface.reference != ReferenceKind::Golden {
                check.status = "missing".into();
                raise(Decision::Reject, &mut decision);
                trace.push(format!(
                    "reject: designed hole `{}` ({} mm at {}, {} mm) is missing",
                    f.name,
                    fmt(f.diameter_mm),
                    fmt(f.x_mm),
                    fmt(f.y_mm)
                ));
            }
        }
        features.push(check);
    }
    // 2. Whole-part tolerances.
    if let (Some(t), Some(tol)) = (facts.thickness_mm, product.tolerances.thickness_mm) {
        let nominal = product.geometry.thickness_mm;
        if (t - nominal).abs() > tol {
            raise(Decision::Reject, &mut decision);
            trace.push(format!(
                "reject: thickness {t:.3} mm, nominal {} ± {} mm",
                fmt(nominal),
                fmt(tol)
            ));
        } else {
            trace.push(format!(
                "thickness {t:.3} mm within {} ± {} mm",
                fmt(nominal),
                fmt(tol)
            ));
        }
    }
    if let (Some(f), Some(tol)) = (facts.flatness_mm, product.tolerances.flatness_mm) {
        if f > tol {
            raise(Decision::Reject, &mut decision);
            trace.push(format!("reject: flatness {f:.3} mm, limit {} mm", fmt(tol)));
        } else {
            trace.push(format!("flatness {f:.3} mm within {} mm", fmt(tol)));
        }
    }
    // 3. Defects: standards and causes.
    let mut counts = std::collections::HashMap::new();
    for (i, d) in detection.defects.iter().enumerate() {
        if designed_of[i].is_none() {
            *counts.entry(d.kind).or_insert(0usize) += 1;
        }
    }
    let mut assessed = Vec::new();
    let mut diagnosis: Vec<CauseCertainty> = Vec::new();
    for (i, d) in detection.defects.iter().enumerate() {
        if designed_of[i].is_some() {
            continue;
        }
        let p = to_product(d.centroid_mm);
        let rec = facts.recurrence.get(i).copied().unwrap_or(0.0);
        let count = counts.get(&d.kind).copied().unwrap_or(0);
        let value = |m: Measure| measure(m, d, p, product, count, rec);
        let zone = product.zones.iter().find(|z| z.contains(p[0], p[1]));
        let label = format!(
            "{} #{} at ({:.1}, {:.1}) mm{}",
            d.kind.name(),
            i + 1,
            p[0],
            p[1],
            zone.map(|z| format!(" in zone `{}`", z.name))
                .unwrap_or_default()
        );
        let mut this = Decision::Accept;
        let mut reasons = Vec::new();
        if let Some(z) = zone {
            if let Some(limit) = z.max_depth_mm.filter(|l| d.depth_mm > *l) {
                this = this.max(Decision::Reject);
                reasons.push(format!(
                    "reject: {label}: depth {:.3} mm > zone limit {} mm",
                    d.depth_mm,
                    fmt(limit)
                ));
            }
            if let Some(limit) = z.max_area_mm2.filter(|l| d.area_mm2 > *l) {
                this = this.max(Decision::Reject);
                reasons.push(format!(
                    "reject: {label}: area {:.2} mm² > zone limit {} mm²",
                    d.area_mm2,
                    fmt(limit)
                ));
            }
        }
        let mut matched_any = false;
        for st in &method.standards {
            if st.kind != "any" && st.kind != d.kind.name() {
                continue;
            }
            if let Some(zn) = &st.zone {
                if zone.is_none_or(|z| &z.name != zn) {
                    continue;
                }
            }
            matched_any = true;
            let fires = match (st.measure, st.above) {
                (Some(m), Some(a)) => {
                    let v = value(m);
                    (v > a).then(|| {
                        format!(
                            "{}: {label}: {} {}{} > {}{}",
                            st.decision.name(),
                            m.name(),
                            fmt(v),
                            unit(m),
                            fmt(a),
                            unit(m)
                        )
                    })
                }
                _ => Some(format!(
                    "{}: {label}: every {} leads to {}",
                    st.decision.name(),
                    if st.kind == "any" {
                        "defect"
                    } else {
                        st.kind.as_str()
                    },
                    st.decision.name()
                )),
            };
            if let Some(r) = fires {
                this = this.max(st.decision);
                reasons.push(r);
            }
        }
        if !matched_any && reasons.is_empty() {
            // No standard speaks about this defect: a person must look (never a silent accept).
            this = Decision::Rework;
            reasons.push(format!(
                "rework: {label}: no standard of method `{}` covers it; check it by hand",
                method.name
            ));
        } else if reasons.is_empty() {
            reasons.push(format!("accept: {label}: within every limit"));
        }
        raise(this, &mut decision);
        let causes = causes_for(process, d, value);
        for (c, why) in causes
            .iter()
            .filter(|c| c.0.certainty >= MIN_CERTAINTY)
            .take(3)
        {
            reasons.push(format!(
                "  probable cause of {} #{}: {} {:.2} ({why})",
                d.kind.name(),
                i + 1,
                c.cause,
                c.certainty
            ));
        }
        if causes.iter().all(|c| c.0.certainty < MIN_CERTAINTY) {
            reasons.push(format!(
                "  no cause of process `{}` explains this {}",
                process.name,
                d.kind.name()
            ));
        }
        for (c, _) in causes.iter().filter(|c| c.0.certainty >= MIN_CERTAINTY) {
            match diagnosis.iter_mut().find(|x| x.cause == c.cause) {
                Some(x) => x.certainty = x.certainty.max(c.certainty),
                None => diagnosis.push(c.clone()),
            }
        }
        trace.extend(reasons.iter().cloned());
        assessed.push(AssessedDefect {
            index: i,
            kind: d.kind.name().into(),
            product_xy_mm: p,
            zone: zone.map(|z| z.name.clone()),
            decision: this,
            reasons,
            causes: causes.into_iter().map(|c| c.0).collect(),
        });
    }
    diagnosis.sort_by(|a, b| b.certainty.total_cmp(&a.certainty));
    if decision == Decision::Accept && detection.coverage < method.surface.min_coverage {
        decision = Decision::Incomplete;
        trace.push(format!(
            "incomplete: only {:.0}% of the outline holds data (method `{}` needs {:.0}%)",
            100.0 * detection.coverage,
            method.name,
            100.0 * method.surface.min_coverage
        ));
    }
    let mut head = format!("{}: ", decision.name());
    head += &match (assessed.len(), decision) {
        (0, Decision::Accept) => "no defect on the measured surface".to_string(),
        (n, _) => format!("{n} defect(s)"),
    };
    if let Some(top) = diagnosis.first() {
        head += &format!(
            "; probable cause: {}",
            diagnosis
                .iter()
                .take(3)
                .map(|c| format!("{} ({:.2})", c.cause, c.certainty))
                .collect::<Vec<_>>()
                .join(", ")
        );
        if !top.remedy.is_empty() {
            head += &format!("; remedy: {}", top.remedy);
        }
    }
    trace.insert(0, head);
    Ok(Assessment {
        product: product.name.clone(),
        decision,
        defects: assessed,
        features,
        diagnosis,
        trace,
        frame_origin_mm: origin,
    })
}

/// A batch's diagnosis: for each cause, the mean over the parts of the part's certainty (parts without the cause
/// count 0), and the share of parts where it is the top cause; ranked by the mean.
pub fn diagnose_batch(parts: &[Vec<CauseCertainty>]) -> Vec<(CauseCertainty, f64)> {
    let mut out: Vec<(CauseCertainty, f64, f64)> = Vec::new();
    for part in parts {
        for (k, c) in part.iter().enumerate() {
            let top = if k == 0 { 1.0 } else { 0.0 };
            match out.iter_mut().find(|x| x.0.cause == c.cause) {
                Some(x) => {
                    x.1 += c.certainty;
                    x.2 += top;
                }
                None => out.push((c.clone(), c.certainty, top)),
            }
        }
    }
    let n = parts.len().max(1) as f64;
    let mut ranked: Vec<(CauseCertainty, f64)> = out
        .into_iter()
        .map(|(mut c, sum, top)| {
            c.certainty = sum / n;
            (c, top / n)
        })
        .collect();
    ranked.sort_by(|a, b| b.0.certainty.total_cmp(&a.0.certainty));
    ranked
}

/// Thickness and flatness from a fitted plane reference (nothing from a golden scan or a quadratic): thickness is
/// the plane's height at the centre of the part's outline; flatness the spread (0.5th to 99.5th percentile) of the
/// deviation over the part's surface cells outside every defect's bounding box.
pub fn part_facts(range: &RangeImage, inspection: &Inspection, recurrence: Vec<f64>) -> PartFacts {
    let d = &inspection.detection;
    let mut facts = PartFacts {
        recurrence,
        ..PartFacts::default()
    };
    let ReferenceInfo::Fitted(r) = &inspection.reference else {
        return facts;
    };
    facts.fitted_reference = true;
    if r.shape != ReferenceShape::Plane {
        return facts;
    }
    let o = frame_origin(d);
    facts.thickness_mm = Some(r.height(o[0], o[1]));
    let m = &inspection.maps;
    let w = range.width.max(1);
    let mut dev: Vec<f64> = Vec::new();
    for (k, (&c, &v)) in m.class.iter().zip(&m.deviation_mm).enumerate() {
        if c != CellClass::Part || !v.is_finite() {
            continue;
        }
        let (x, y) = cell_xy(range, k % w, k / w);
        let inside = d.defects.iter().any(|f| {
            x >= f.bbox_mm[0] - 1.0
                && x <= f.bbox_mm[2] + 1.0
                && y >= f.bbox_mm[1] - 1.0
                && y <= f.bbox_mm[3] + 1.0
        });
        if !inside {
            dev.push(f64::from(v));
        }
    }
    if dev.len() >= 100 {
        dev.sort_by(f64::total_cmp);
        let q = |p: f64| dev[((dev.len() - 1) as f64 * p).round() as usize];
        facts.flatness_mm = Some(q(0.995) - q(0.005));
    }
    facts
}

/// Inspects `range` as `method` says (reference, threshold, confidence) with `rules` (see
/// [`KnowledgeBase::surface_rules`]); a golden method needs `golden`.
pub fn inspect_with(
    method: &Method,
    rules: &mut SurfaceRules,
    range: &RangeImage,
    golden: Option<&RangeImage>,
) -> Result<Inspection, CoreError> {
    let source = match (method.surface.fitted_shape(), golden) {
        (_, Some(g)) => ReferenceSource::Golden(g),
        (Some(shape), None) => ReferenceSource::Fit(shape),
        (None, None) => {
            return Err(CoreError::Inspection(InspectionError::GoldenNeeded {
                method: method.name.clone(),
            }));
        }
    };
    inspect(
        range,
        source,
        &CharacterizeParams::default(),
        rules,
        &method.surface.detect_params(),
    )
}

/// The method a product is inspected with.
pub fn method_of<'a>(kb: &'a KnowledgeBase, product: &str) -> Result<&'a Method, KbError> {
    Ok(kb.product_context(product)?.2)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::KnowledgeBase;

    #[test]
    fn certainty_factors_combine_as_mycin() {
        assert!((combine(0.6, 0.5) - 0.8).abs() < 1e-12);
        assert!((combine(-0.6, -0.5) + 0.8).abs() < 1e-12);
        assert!((combine(0.6, -0.5) - 0.2).abs() < 1e-12);
        assert!((combine(0.3, 0.0) - 0.3).abs() < 1e-12);
        // Order does not matter.
        assert!((combine(combine(0.2, 0.7), -0.4) - combine(combine(-0.4, 0.7), 0.2)).abs() < 0.05);
    }

    fn defect(kind: DefectKind, x: f64, y: f64, area: f64, depth: f64) -> Defect {
        Defect {
            kind,
            centroid_mm: [x, y],
            bbox_mm: [x - 1.0, y - 1.0, x + 1.0, y + 1.0],
            area_mm2: area,
            depth_mm: depth,
            volume_mm3: 1.0,
            confidence: 0.8,
            bottom_seen: false,
            evidence: Default::default(),
        }
    }

    #[test]
    fn designed_holes_are_checked_and_uncovered_kinds_go_to_a_person() {
        // The shipped knowledge base with the anomaly standard taken out of method stripes-11.
        let mut files: Vec<crate::SourceFile> = crate::SHIPPED_FILES
            .iter()
            .map(|(p, t)| crate::SourceFile {
                path: (*p).into(),
                text: (*t).into(),
            })
            .collect();
        for f in &mut files {
            if f.path == "methods/stripes-11.toml" {
                f.text = f.text.replace(
                    "[[standard]]\nkind = \"anomaly\"\ndecision = \"rework\"\n",
                    "",
                );
            }
        }
        let kb = KnowledgeBase::from_files(&files).expect("kb");
        // The part's outline is offset by (5, 0): the product frame follows it.
        let detection = Detection {
            defects: vec![
                // Mounting hole 1 at (-28, 18), 7 mm across: out of its ±0.4 mm tolerance.
                defect(
                    DefectKind::Hole,
                    -23.0,
                    18.0,
                    std::f64::consts::PI * 3.5 * 3.5,
                    10.0,
                ),
                // An anomaly outside the gasket seat: no standard covers it any more.
                defect(DefectKind::Anomaly, 35.0, 25.0, 3.0, 0.4),
            ],
            coverage: 0.97,
            part_bbox_mm: [-35.0, -30.0, 45.0, 30.0],
            ..Detection::default()
        };
        let facts = PartFacts {
            fitted_reference: true,
            ..PartFacts::default()
        };
        let a = assess(&kb, "cover-plate", &detection, &facts).expect("assess");
        assert_eq!(a.frame_origin_mm, [5.0, 0.0]);
        assert_eq!(a.decision, Decision::Reject);
        let status: Vec<&str> = a.features.iter().map(|f| f.status.as_str()).collect();
        assert_eq!(status, ["out-of-tolerance", "missing"]);
        assert_eq!(a.defects.len(), 1, "the designed hole is not a defect");
        assert_eq!(a.defects[0].decision, Decision::Rework);
        assert!(
            a.defects[0].reasons[0].contains("no standard"),
            "{:?}",
            a.defects[0].reasons
        );
        assert!(
            a.trace
                .iter()
                .any(|t| t.contains("`mounting hole 2`") && t.contains("missing"))
        );
        // Against a golden scan a designed hole cannot be seen as such: not called missing.
        let golden = PartFacts::default();
        let b = assess(
            &kb,
            "cover-plate",
            &Detection {
                defects: vec![],
                ..detection
            },
            &golden,
        )
        .expect("assess");
        assert!(
            b.features.iter().all(|f| f.status == "not-checked"),
            "{:?}",
            b.features
        );
        assert_eq!(b.decision, Decision::Accept);
    }

    #[test]
    fn recurrence_counts_parts_not_defects() {
        let h = vec![
            vec![
                (DefectKind::Dent, [10.0, -6.0]),
                (DefectKind::Dent, [10.5, -6.0]),
            ],
            vec![(DefectKind::Bump, [10.0, -6.0])],
            vec![(DefectKind::Dent, [30.0, 0.0])],
            vec![],
        ];
        assert_eq!(recurrence(&h, DefectKind::Dent, [10.2, -6.1]), 0.25);
        assert_eq!(recurrence(&[], DefectKind::Dent, [0.0, 0.0]), 0.0);
    }
}
