//! Conformance with fuzzylite: every example engine in `../shared/fuzzylite-examples` that comes with an `.fld`
//! (inputs and the outputs fuzzylite's C++ library computed) is evaluated row by row, from its `.fll` and from its
//! `.fcl`, and each output compared: NaN must match NaN, otherwise |ours − reference| <= 1e-3 · max(1, |reference|).
//! The examples are read in place, never copied; without them the test says it skipped.

use std::path::{Path, PathBuf};
use stripe3d_fuzzy::{Engine, fcl, fld, fll};

fn examples() -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/fuzzylite-examples");
    p.is_dir().then_some(p)
}

/// Compares an engine with the reference table; returns (rows, worst relative error, first mismatch).
fn compare(engine: &mut Engine, table: &fld::Table) -> (usize, f64, Option<String>) {
    let cols = fld::input_columns(engine, table).expect("inputs in header");
    let outs: Vec<usize> = engine
        .outputs
        .iter()
        .map(|o| {
            table
                .columns
                .iter()
                .position(|c| *c == o.name)
                .expect("output in header")
        })
        .collect();
    let mut worst: f64 = 0.0;
    let mut first = None;
    for (line, row) in &table.rows {
        for (i, &c) in cols.iter().enumerate() {
            engine.set_input(i, row[c]);
        }
        engine.process().expect("process");
        for (k, &c) in outs.iter().enumerate() {
            let (ours, reference) = (engine.output_value(k), row[c]);
            let ok = if reference.is_nan() || ours.is_nan() {
                reference.is_nan() && ours.is_nan()
            } else {
                let err = (ours - reference).abs() / reference.abs().max(1.0);
                worst = worst.max(err);
                err <= 1e-3
            };
            if !ok && first.is_none() {
                first = Some(format!(
                    "line {line}: {} = {ours} but fuzzylite gives {reference}",
                    engine.outputs[k].name
                ));
            }
            if !ok && (ours.is_nan() || reference.is_nan()) {
                worst = f64::INFINITY;
            }
        }
    }
    (table.rows.len(), worst, first)
}

#[test]
fn every_example_engine_matches_fuzzylite() {
    let Some(root) = examples() else {
        eprintln!("SKIPPED: ../shared/fuzzylite-examples not found beside the checkout");
        return;
    };
    let mut files = Vec::new();
    files_with(&root, "fld", &mut files);
    assert!(files.len() >= 32, "found only {} .fld files", files.len());
    let mut failures = Vec::new();
    let mut report = String::new();
    for f in &files {
        let table = fld::parse(&std::fs::read_to_string(f).expect("read fld")).expect("parse fld");
        let name = f.strip_prefix(&root).unwrap_or(f).with_extension("");
        for (ext, reader) in [
            ("fll", fll::read as fn(&str) -> _),
            ("fcl", fcl::read as fn(&str) -> _),
        ] {
            let path = f.with_extension(ext);
            let Ok(text) = std::fs::read_to_string(&path) else {
                continue;
            };
            match reader(&text) {
                Err(e) => failures.push(format!("{}.{ext}: cannot load: {e}", name.display())),
                Ok(mut engine) => {
                    let (rows, worst, first) = compare(&mut engine, &table);
                    report.push_str(&format!(
                        "{:<45} {ext} {rows:>5} rows  worst relative error {worst:.2e}\n",
                        name.display()
                    ));
                    if let Some(m) = first {
                        failures.push(format!("{}.{ext}: {m}", name.display()));
                    }
                }
            }
        }
    }
    eprintln!("{report}");
    assert!(
        failures.is_empty(),
        "{} engine descriptions differ from fuzzylite:\n{}",
        failures.len(),
        failures.join("\n")
    );
}

fn files_with(dir: &Path, ext: &str, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    let mut entries: Vec<_> = entries.flatten().map(|e| e.path()).collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            files_with(&p, ext, out);
        } else if p.extension().is_some_and(|e| e == ext) {
            out.push(p);
        }
    }
}

#[test]
fn every_example_fll_round_trips_exactly() {
    let Some(root) = examples() else {
        eprintln!("SKIPPED: ../shared/fuzzylite-examples not found beside the checkout");
        return;
    };
    let mut files = Vec::new();
    files_with(&root, "fll", &mut files);
    assert!(files.len() >= 32);
    for f in &files {
        let engine = match fll::read(&std::fs::read_to_string(f).expect("read")) {
            Ok(e) => e,
            Err(e) => panic!("{}: {e}", f.display()),
        };
        let text = fll::write(&engine);
        let again = fll::read(&text)
            .unwrap_or_else(|e| panic!("{}: written FLL does not read back: {e}", f.display()));
        assert!(
            again == engine,
            "{}: engine changed in the round trip",
            f.display()
        );
        assert_eq!(
            fll::write(&again),
            text,
            "{}: FLL text changed in the round trip",
            f.display()
        );
    }
    let mut fcls = Vec::new();
    files_with(&root, "fcl", &mut fcls);
    for f in &fcls {
        if let Err(e) = fcl::read(&std::fs::read_to_string(f).expect("read")) {
            panic!("{}: {e}", f.display());
        }
    }
}
