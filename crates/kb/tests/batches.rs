//! End to end on simulated batches: plates from a process with a seeded fault, measured (idealised range images:
//! the scene's exact heights plus the scan's noise), inspected with the product's method, and reasoned about with the
//! shipped knowledge base. The whole-chain figures from rendered frames are `stripe3d bench defects`.

use stripe3d_core::detect::{DefectKind, Inspection};
use stripe3d_kb::learn::{Mark, label_by_position, score, tune_rules};
use stripe3d_kb::reason::{diagnose_batch, frame_origin, inspect_with, part_facts, recurrence};
use stripe3d_kb::{KnowledgeBase, assess, shipped};
use stripe3d_sim::DefectTruth;
use stripe3d_sim::batch::{
    DESIGNED_HOLES, ProcessFault, SCAN_NOISE_MM, batch_plate, ideal_range, kind_f1, match_defects,
    match_radius_mm,
};

/// Range grid of these tests, mm: twice the default cell keeps the batches quick in a debug build.
const GRID_MM: f64 = 0.2;

fn kb() -> KnowledgeBase {
    shipped().expect("knowledge base")
}

struct Part {
    inspection: Inspection,
    truth: Vec<DefectTruth>,
    range: stripe3d_core::accumulate::RangeImage,
}

fn measure(kb: &KnowledgeBase, product: &str, fault: ProcessFault, seed: u64, part: u64) -> Part {
    let method = stripe3d_kb::reason::method_of(kb, product).expect("method");
    let mut rules = kb.surface_rules(method).expect("rules");
    let scene = batch_plate(fault, seed, part);
    let (range, truth) = ideal_range(&scene, GRID_MM, SCAN_NOISE_MM, part).expect("range");
    let inspection = inspect_with(method, &mut rules, &range, None).expect("inspection");
    let d = &inspection.detection;
    for c in &d.candidates {
        assert_eq!(c.reported, c.defect.is_some());
        if let Some(k) = c.defect {
            assert_eq!(
                d.defects[k].kind, c.kind,
                "candidates point at their defects"
            );
        }
    }
    assert_eq!(
        d.candidates.iter().filter(|c| c.reported).count(),
        d.defects.len()
    );
    Part {
        inspection,
        truth,
        range,
    }
}

/// Runs a batch through reasoning with the history of the batch so far; returns the batch diagnosis's causes
/// ranked.
fn batch(kb: &KnowledgeBase, product: &str, fault: ProcessFault, parts: u64) -> Vec<(String, f64)> {
    let mut history: Vec<stripe3d_kb::reason::PartDefects> = Vec::new();
    let mut diagnoses = Vec::new();
    for k in 0..parts {
        let p = measure(kb, product, fault, 7, k);
        let d = &p.inspection.detection;
        let o = frame_origin(d);
        let local = |c: [f64; 2]| [c[0] - o[0], c[1] - o[1]];
        let rec: Vec<f64> = d
            .defects
            .iter()
            .map(|x| recurrence(&history, x.kind, local(x.centroid_mm)))
            .collect();
        let facts = part_facts(&p.range, &p.inspection, rec);
        let a = assess(kb, product, d, &facts).expect("assessment");
        // A designed hole is never a defect, and both are found.
        for x in &a.defects {
            for (hx, hy, _) in DESIGNED_HOLES {
                let q = x.product_xy_mm;
                assert!(
                    (q[0] - hx).hypot(q[1] - hy) > 4.0,
                    "{fault:?} part {k}: designed hole reported as {} at {q:?}",
                    x.kind
                );
            }
        }
        assert!(
            a.features.iter().all(|f| f.status == "found"),
            "{fault:?} part {k}: {:?}",
            a.features
        );
        // Every truth defect is reported (idealised data: the detection's recall is not in question here).
        let o = match_defects(&p.truth, &d.defects);
        assert!(
            o.matches.iter().all(|m| m.found.is_some()),
            "{fault:?} part {k}: missed {:?}",
            o.matches
        );
        history.push(
            a.defects
                .iter()
                .map(|x| {
                    (
                        DefectKind::from_name(&x.kind).expect("kind"),
                        x.product_xy_mm,
                    )
                })
                .collect(),
        );
        diagnoses.push(a.diagnosis);
    }
    diagnose_batch(&diagnoses)
        .into_iter()
        .map(|(c, _)| (c.cause, c.certainty))
        .collect()
}

#[test]
fn seeded_process_faults_give_the_right_ranked_diagnosis() {
    let kb = kb();
    let debris = batch(&kb, "cover-plate", ProcessFault::DieDebris, 8);
    assert_eq!(debris[0].0, "die-debris", "die debris batch: {debris:?}");
    assert!(
        debris[0].1 > 0.7 && debris[0].1 > debris[1].1 + 0.3,
        "{debris:?}"
    );
    let knocks = batch(&kb, "cover-plate", ProcessFault::Handling, 8);
    assert_eq!(knocks[0].0, "handling-damage", "handling batch: {knocks:?}");
    let pores = batch(&kb, "cast-cover", ProcessFault::Porosity, 4);
    assert_eq!(pores[0].0, "gas-porosity", "porosity batch: {pores:?}");
    assert!(pores[0].1 > 0.8, "{pores:?}");
}

#[test]
fn a_healthy_batch_is_accepted_and_its_verdicts_follow_the_standards() {
    let kb = kb();
    let mut verdicts = Vec::new();
    for k in 0..5 {
        let p = measure(&kb, "cover-plate", ProcessFault::Healthy, 3, k);
        let facts = part_facts(&p.range, &p.inspection, vec![]);
        let t = facts.thickness_mm.expect("thickness from a plane");
        assert!((t - 10.0).abs() < 0.01, "thickness {t}");
        assert!(facts.flatness_mm.expect("flatness") < 0.1);
        let a = assess(&kb, "cover-plate", &p.inspection.detection, &facts).expect("assessment");
        // Bumps of the healthy batch are 0.1-0.3 mm high: rework (every bump), but reject in the gasket seat
        // (|x| <= 20, |y| <= 12 mm, 0.1 mm limit).
        let expected = match p.truth.first() {
            None => "accept",
            Some(t) if t.x_mm.abs() <= 20.0 && t.y_mm.abs() <= 12.0 => "reject",
            Some(_) => "rework",
        };
        assert_eq!(a.decision.name(), expected, "part {k}: {:#?}", a.trace);
        assert!(a.trace[0].starts_with(expected));
        verdicts.push(a.decision);
    }
    assert!(verdicts.iter().any(|v| v.name() == "accept"));
}

/// Simulated operator: labels from the truth.
fn marks(truth: &[DefectTruth]) -> Vec<Mark> {
    truth
        .iter()
        .map(|t| Mark {
            kind: DefectKind::from_name(&t.kind),
            at_mm: [t.x_mm, t.y_mm],
            radius_mm: match_radius_mm(t),
        })
        .collect()
}

#[test]
fn learning_from_labelled_parts_raises_the_f1_on_a_held_out_batch() {
    let kb = shipped().expect("kb");
    let method = stripe3d_kb::reason::method_of(&kb, "machined-cover").expect("method");
    let params = method.surface.detect_params();
    let shipped_rules = kb.surface_rules(method).expect("rules");
    let (mut data, mut missed) = (Vec::new(), 0);
    for k in 0..20 {
        let p = measure(&kb, "machined-cover", ProcessFault::ToolMarks, 11, k);
        let (l, m) = label_by_position(&p.inspection.detection.candidates, &marks(&p.truth));
        // Designed holes are labelled holes by nobody: leave them out as the history does.
        data.extend(
            l.into_iter()
                .filter(|x| x.truth.is_some() || x.evidence.gap_mm < 5.0),
        );
        missed += m;
    }
    let (engine, report) = tune_rules(&shipped_rules, &params, &data, missed).expect("tuning");
    assert!(report.after.f1() > report.before.f1(), "{report:?}");
    // Held out: a new batch, inspected with the shipped and with the tuned rules.
    let f1_with = |rules: &stripe3d_core::detect::SurfaceRules| {
        let mut outcomes = Vec::new();
        for k in 100..120 {
            let scene = batch_plate(ProcessFault::ToolMarks, 11, k);
            let (range, truth) = ideal_range(&scene, GRID_MM, SCAN_NOISE_MM, k).expect("range");
            let i = inspect_with(method, &mut rules.clone(), &range, None).expect("inspection");
            let a = assess(
                &kb,
                "machined-cover",
                &i.detection,
                &part_facts(&range, &i, vec![]),
            )
            .expect("assess");
            let real: Vec<_> = a
                .defects
                .iter()
                .map(|x| i.detection.defects[x.index].clone())
                .collect();
            outcomes.push(match_defects(&truth, &real));
        }
        kind_f1(&outcomes)
    };
    let before = f1_with(&shipped_rules);
    let tuned = stripe3d_core::detect::SurfaceRules::from_engine(engine).expect("tuned");
    let after = f1_with(&tuned);
    assert!(
        before.0 < 0.9,
        "the shipped rules misclassify short gouges: {before:?}"
    );
    assert!(
        after.0 > before.0 + 0.1,
        "held-out F1 {before:?} -> {after:?}"
    );
    // And the tuned rules score on the training data as the report says.
    assert_eq!(
        score(&mut tuned.clone(), &params, &data, missed).expect("score"),
        report.after
    );
}
