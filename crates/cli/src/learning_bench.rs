//! `stripe3d bench knowledge`: the knowledge base on simulated batches.
//!
//! 1. Diagnosis: batches of parts from a process with a seeded fault (die debris, handling, porosity, a chipped
//!    tool), each part inspected with its product's method and reasoned about with the history of the batch so
//!    far; the batch diagnosis ranks the causes.
//! 2. Learning: a machined batch with short tool marks, which the shipped rules call dents. Training parts are
//!    inspected and recorded in a history database; a simulated operator gives feedback from the truth (confirm,
//!    correct the kind, false alarm, missed at x, y); `learn` writes knowledge-base version 2 from the history; a
//!    held-out batch is inspected with v1 and v2 and scored against the truth (defect F1, kind must match).
//!
//! Parts are idealised range images ([`stripe3d_sim::batch::ideal_range`]: exact heights plus the scan's noise) so
//! that batches of a hundred parts take seconds; what is measured is everything downstream of the range image.

use crate::inspect::{ProductContext, history_record};
use crate::knowledge::learn_from_history;
use anyhow::{Context, Result};
use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;
use stripe3d_core::accumulate::RangeImage;
use stripe3d_core::detect::{DefectKind, Inspection, SurfaceRules};
use stripe3d_io::history::{Feedback, History, Judgement};
use stripe3d_kb::reason::{
    diagnose_batch, frame_origin, inspect_with, method_of, part_facts, recurrence,
};
use stripe3d_kb::{Assessment, KnowledgeBase, assess};
use stripe3d_sim::DefectTruth;
use stripe3d_sim::batch::{
    PartOutcome, ProcessFault, SCAN_NOISE_MM, batch_plate, ideal_range, kind_f1, match_defects,
};

struct Part {
    range: RangeImage,
    truth: Vec<DefectTruth>,
    inspection: Inspection,
}

fn bar(n: usize, what: &str) -> ProgressBar {
    let pb = ProgressBar::new(n as u64);
    pb.set_style(
        ProgressStyle::with_template("{msg:>28} [{bar:30}] {pos}/{len} parts ({eta})")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    pb.set_message(what.to_string());
    pb
}

/// A simulated batch: the process fault, its seed and the range grid.
#[derive(Clone, Copy)]
struct Batch {
    fault: ProcessFault,
    seed: u64,
    grid_mm: f64,
}

/// Inspects parts `parts` of a batch in parallel with `rules`.
fn inspect_parts(
    kb: &KnowledgeBase,
    product: &str,
    rules: &SurfaceRules,
    batch: Batch,
    parts: std::ops::Range<u64>,
    what: &str,
) -> Result<Vec<Part>> {
    let Batch {
        fault,
        seed,
        grid_mm,
    } = batch;
    let method = method_of(kb, product)?;
    let pb = bar(parts.clone().count(), what);
    let out = parts
        .into_par_iter()
        .map(|k| -> Result<Part> {
            let scene = batch_plate(fault, seed, k);
            let (range, truth) = ideal_range(&scene, grid_mm, SCAN_NOISE_MM, k)?;
            let inspection = inspect_with(method, &mut rules.clone(), &range, None)
                .with_context(|| format!("part {k}"))?;
            pb.inc(1);
            Ok(Part {
                range,
                truth,
                inspection,
            })
        })
        .collect::<Result<Vec<_>>>();
    pb.finish_and_clear();
    out
}

/// Reasons about the parts in order, each with the batch so far as its history.
fn assess_in_order(kb: &KnowledgeBase, product: &str, parts: &[Part]) -> Result<Vec<Assessment>> {
    let mut history: Vec<stripe3d_kb::reason::PartDefects> = Vec::new();
    let mut out = Vec::new();
    for p in parts {
        let d = &p.inspection.detection;
        let o = frame_origin(d);
        let rec = d
            .defects
            .iter()
            .map(|x| {
                recurrence(
                    &history,
                    x.kind,
                    [x.centroid_mm[0] - o[0], x.centroid_mm[1] - o[1]],
                )
            })
            .collect();
        let a = assess(kb, product, d, &part_facts(&p.range, &p.inspection, rec))?;
        history.insert(
            0,
            a.defects
                .iter()
                .filter_map(|x| Some((DefectKind::from_name(&x.kind)?, x.product_xy_mm)))
                .collect(),
        );
        history.truncate(20);
        out.push(a);
    }
    Ok(out)
}

/// Real (not designed) defects of a part matched to its truth.
fn outcome(p: &Part, a: &Assessment) -> PartOutcome {
    let real: Vec<_> = a
        .defects
        .iter()
        .map(|x| p.inspection.detection.defects[x.index].clone())
        .collect();
    match_defects(&p.truth, &real)
}

/// Runs `stripe3d bench knowledge`.
pub fn bench_knowledge(parts: usize, held_out: usize, seed: u64, grid_mm: f64) -> Result<()> {
    let kb = stripe3d_kb::shipped()?;
    let started = std::time::Instant::now();
    let batch = parts.clamp(4, 500) as u64;
    say!("## Diagnosis of seeded-fault batches ({batch} parts each, grid {grid_mm} mm)\n");
    say!("| batch | product (process) | 1st cause | 2nd cause | 3rd cause | right |");
    say!("|---|---|---|---|---|---|");
    let batches = [
        (
            "die debris",
            "cover-plate",
            ProcessFault::DieDebris,
            "die-debris",
        ),
        (
            "handling",
            "cover-plate",
            ProcessFault::Handling,
            "handling-damage",
        ),
        (
            "porosity",
            "cast-cover",
            ProcessFault::Porosity,
            "gas-porosity",
        ),
        (
            "chipped tool",
            "machined-cover",
            ProcessFault::ToolMarks,
            "chipped-tool",
        ),
    ];
    let mut right = 0;
    for (name, product, fault, expected) in batches {
        let method = method_of(&kb, product)?;
        let rules = kb.surface_rules(method)?;
        let ps = inspect_parts(
            &kb,
            product,
            &rules,
            Batch {
                fault,
                seed,
                grid_mm,
            },
            0..batch,
            name,
        )?;
        let assessed = assess_in_order(&kb, product, &ps)?;
        let ranked = diagnose_batch(
            &assessed
                .iter()
                .map(|a| a.diagnosis.clone())
                .collect::<Vec<_>>(),
        );
        let cell = |k: usize| {
            ranked
                .get(k)
                .map(|(c, _)| format!("{} {:.2}", c.cause, c.certainty))
                .unwrap_or_else(|| "-".into())
        };
        let ok = ranked.first().is_some_and(|(c, _)| c.cause == expected);
        right += usize::from(ok);
        let process = &kb.product_context(product)?.1.name;
        say!(
            "| {name} | {product} ({process}) | {} | {} | {} | {} |",
            cell(0),
            cell(1),
            cell(2),
            if ok { "yes" } else { "NO" }
        );
    }
    say!("\n{right} of 4 batches diagnosed with the seeded cause first.\n");

    // Learning.
    let product = "machined-cover";
    let method = method_of(&kb, product)?;
    let shipped_rules = kb.surface_rules(method)?;
    let parts = parts.clamp(5, 500) as u64;
    let held_out = held_out.clamp(1, 500) as u64;
    let dir = tempfile_dir()?;
    let db = dir.join("history.sqlite");
    let mut history = History::open(&db)?;
    let ctx = ProductContext {
        kb: kb.clone(),
        kb_dir: None,
        name: product.into(),
    };
    let train = inspect_parts(
        &kb,
        product,
        &shipped_rules,
        Batch {
            fault: ProcessFault::ToolMarks,
            seed: seed + 1,
            grid_mm,
        },
        0..parts,
        "training parts (v1)",
    )?;
    let assessed = assess_in_order(&kb, product, &train)?;
    let mut judgements = [0usize; 4];
    for (k, (p, a)) in train.iter().zip(&assessed).enumerate() {
        let record = history_record(
            format!("train-{k}"),
            None,
            Some(&ctx),
            &p.inspection,
            Some(a),
            a.decision.name(),
        );
        let id = history.record(&record)?;
        // The simulated operator: every real defect judged against the truth.
        let mut fb = |judgement, defect_id, kind, at_mm, cause: Option<&str>| {
            history.add_feedback(&Feedback {
                inspection: id,
                judgement,
                defect_id,
                kind,
                at_mm,
                cause: cause.map(String::from),
                operator: Some("simulated operator".into()),
                note: None,
            })
        };
        let d = &p.inspection.detection;
        let o = outcome(p, a);
        let index_of = |f: &stripe3d_core::detect::Defect| d.defects.iter().position(|x| x == f);
        for m in &o.matches {
            let truth_kind = DefectKind::from_name(&m.truth.kind);
            let cause = (m.truth.kind == "scratch").then_some("chipped-tool");
            match m.found.as_ref().and_then(|f| Some((f, index_of(f)?))) {
                Some((f, n)) => {
                    let corrected = (Some(f.kind) != truth_kind).then_some(truth_kind).flatten();
                    judgements[usize::from(corrected.is_some())] += 1;
                    fb(Judgement::Confirmed, Some(n + 1), corrected, None, cause)?;
                }
                None => {
                    judgements[3] += 1;
                    fb(
                        Judgement::Missed,
                        None,
                        truth_kind,
                        Some([m.truth.x_mm, m.truth.y_mm]),
                        cause,
                    )?;
                }
            }
        }
        for f in &o.false_defects {
            if let Some(n) = index_of(f) {
                judgements[2] += 1;
                fb(Judgement::FalseAlarm, Some(n + 1), None, None, None)?;
            }
        }
        fb(Judgement::Reviewed, None, None, None, None)?;
    }
    let learned = learn_from_history(&ctx, &history)?;
    let tuned_method = method_of(&learned.kb, product)?;
    let tuned_rules = learned.kb.surface_rules(tuned_method)?;
    let held = |rules: &SurfaceRules,
                kb: &KnowledgeBase,
                what: &str|
     -> Result<(f64, usize, usize, usize)> {
        let ps = inspect_parts(
            kb,
            product,
            rules,
            Batch {
                fault: ProcessFault::ToolMarks,
                seed: seed + 2,
                grid_mm,
            },
            1000..1000 + held_out,
            what,
        )?;
        let a = assess_in_order(kb, product, &ps)?;
        let outcomes: Vec<PartOutcome> = ps.iter().zip(&a).map(|(p, a)| outcome(p, a)).collect();
        Ok(kind_f1(&outcomes))
    };
    let before = held(&shipped_rules, &kb, "held-out parts, v1")?;
    let after = held(&tuned_rules, &learned.kb, "held-out parts, v2")?;
    let t = &learned.tuning;
    say!(
        "## Learning from feedback: short tool marks on `{product}` ({parts} labelled parts, {held_out} held out)\n"
    );
    say!(
        "Simulated operator's feedback on the training parts: {} confirmed, {} corrected kind, {} false alarms, {} \
         missed.\n",
        judgements[0],
        judgements[1],
        judgements[2],
        judgements[3]
    );
    say!("| | shipped rules (v1) | learned rules (v2) |");
    say!("|---|---|---|");
    say!(
        "| F1 on the labelled history (candidates re-decided) | {:.3} | {:.3} |",
        t.before.f1(),
        t.after.f1()
    );
    say!(
        "| F1 on the held-out batch (inspected again) | {:.3} | {:.3} |",
        before.0,
        after.0
    );
    say!(
        "| held out: right / false / missed | {} / {} / {} | {} / {} / {} |",
        before.1,
        before.2,
        before.3,
        after.1,
        after.2,
        after.3
    );
    say!("\nWhat learning changed (v1 -> v2):");
    for c in &learned.changes {
        say!("- {c}");
    }
    // The chipped-tool batch of the diagnosis table again, with v2.
    let ps = inspect_parts(
        &learned.kb,
        product,
        &tuned_rules,
        Batch {
            fault: ProcessFault::ToolMarks,
            seed,
            grid_mm,
        },
        0..batch,
        "chipped tool, v2",
    )?;
    let assessed = assess_in_order(&learned.kb, product, &ps)?;
    let ranked = diagnose_batch(
        &assessed
            .iter()
            .map(|a| a.diagnosis.clone())
            .collect::<Vec<_>>(),
    );
    say!(
        "\nThe chipped-tool batch of the diagnosis table, reasoned about with v2: {}.",
        ranked
            .iter()
            .take(3)
            .map(|(c, _)| format!("{} {:.2}", c.cause, c.certainty))
            .collect::<Vec<_>>()
            .join(", ")
    );
    let _ = std::fs::remove_dir_all(&dir);
    say!(
        "\n{:.0} s in all ({} threads).",
        started.elapsed().as_secs_f64(),
        rayon::current_num_threads()
    );
    Ok(())
}

/// A fresh private folder under the system's temporary folder.
fn tempfile_dir() -> Result<std::path::PathBuf> {
    let t = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap_or_default()
        .as_nanos();
    let d = std::env::temp_dir().join(format!("stripe3d-bench-{}-{t}", std::process::id()));
    std::fs::create_dir_all(&d).with_context(|| format!("{}: cannot create", d.display()))?;
    Ok(d)
}
