//! What changed between two knowledge-base versions (`stripe3d kb diff`): every field of every product, process
//! and method, and every term parameter of every rule base.

use crate::model::KnowledgeBase;
use serde_json::Value;
use std::collections::BTreeSet;

fn walk(path: &str, a: Option<&Value>, b: Option<&Value>, out: &mut Vec<String>) {
    match (a, b) {
        (Some(Value::Object(x)), Some(Value::Object(y))) => {
            let keys: BTreeSet<&String> = x.keys().chain(y.keys()).collect();
            for k in keys {
                walk(&format!("{path}.{k}"), x.get(k), y.get(k), out);
            }
        }
        (Some(Value::Array(x)), Some(Value::Array(y))) => {
            for i in 0..x.len().max(y.len()) {
                walk(&format!("{path}[{i}]"), x.get(i), y.get(i), out);
            }
        }
        (Some(x), Some(y)) if x == y => {}
        (Some(x), Some(y)) => out.push(format!("{path}: {x} -> {y}")),
        (Some(x), None) => out.push(format!("{path}: {x} -> (removed)")),
        (None, Some(y)) => out.push(format!("{path}: (new) {y}")),
        (None, None) => {}
    }
}

fn entries<T: serde::Serialize>(
    what: &str,
    a: &std::collections::BTreeMap<String, T>,
    b: &std::collections::BTreeMap<String, T>,
    out: &mut Vec<String>,
) {
    let names: BTreeSet<&String> = a.keys().chain(b.keys()).collect();
    for n in names {
        let va = a.get(n).and_then(|v| serde_json::to_value(v).ok());
        let vb = b.get(n).and_then(|v| serde_json::to_value(v).ok());
        walk(&format!("{what} `{n}`"), va.as_ref(), vb.as_ref(), out);
    }
}

/// Term parameters of a rule base, `variable.term` -> `Class p1 p2 ...`.
fn terms(text: &str) -> std::collections::BTreeMap<String, String> {
    let mut out = std::collections::BTreeMap::new();
    if let Ok(e) = stripe3d_fuzzy::fll::read(text) {
        for v in &e.inputs {
            for t in &v.terms {
                out.insert(
                    format!("{}.{}", v.name, t.name),
                    format!("{} {}", t.shape.class(), t.shape.parameters()),
                );
            }
        }
        for v in &e.outputs {
            for t in &v.terms {
                out.insert(
                    format!("{}.{}", v.name, t.name),
                    format!("{} {}", t.shape.class(), t.shape.parameters()),
                );
            }
        }
        for b in &e.blocks {
            for r in &b.rules {
                out.insert(format!("rule `{}`", r.text), "present".into());
            }
        }
    }
    out
}

/// Readable lines of every difference from `old` to `new` (empty: the same knowledge).
pub fn diff(old: &KnowledgeBase, new: &KnowledgeBase) -> Vec<String> {
    let mut out = Vec::new();
    let ma = serde_json::to_value(&old.manifest).ok();
    let mb = serde_json::to_value(&new.manifest).ok();
    walk("kb", ma.as_ref(), mb.as_ref(), &mut out);
    entries("product", &old.products, &new.products, &mut out);
    entries("process", &old.processes, &new.processes, &mut out);
    entries("method", &old.methods, &new.methods, &mut out);
    let sa = serde_json::to_value(&old.statistics).ok();
    let sb = serde_json::to_value(&new.statistics).ok();
    walk("statistics", sa.as_ref(), sb.as_ref(), &mut out);
    // Rule bases: the shipped one stands for methods that name none.
    let paths: BTreeSet<&String> = old.rules.keys().chain(new.rules.keys()).collect();
    for p in paths {
        let ta = old.rules.get(p).map(|t| terms(t)).unwrap_or_default();
        let tb = new.rules.get(p).map(|t| terms(t)).unwrap_or_default();
        let keys: BTreeSet<&String> = ta.keys().chain(tb.keys()).collect();
        for k in keys {
            match (ta.get(k), tb.get(k)) {
                (Some(x), Some(y)) if x == y => {}
                (Some(x), Some(y)) => out.push(format!("{p}: {k}: {x} -> {y}")),
                (Some(x), None) => out.push(format!("{p}: {k}: {x} -> (removed)")),
                (None, Some(y)) => out.push(format!("{p}: {k}: (new) {y}")),
                (None, None) => {}
            }
        }
    }
    out
}
