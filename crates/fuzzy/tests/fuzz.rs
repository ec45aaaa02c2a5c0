//! Property tests of the parsers: hostile text never panics, and whatever loads evaluates without panicking.
//! Failing cases proptest finds are kept in `proptest-regressions/` and replayed on every run.

use proptest::prelude::*;
use stripe3d_fuzzy::{expr, fcl, fld, fll};

const FLL: &str = "Engine: everything
description: every term class, hedge and activation
InputVariable: a
  enabled: true
  range: 0 10
  lock-range: true
  term: t1 Triangle 0 2 4
  term: t2 Trapezoid 1 2 3 4 0.8
  term: t3 Rectangle 2 5
  term: t4 Gaussian 5 1
  term: t5 GaussianProduct 4 1 6 1
  term: t6 Bell 5 2 3
  term: t7 Sigmoid 5 2
  term: t8 SigmoidDifference 2 3 3 8
  term: t9 SigmoidProduct 2 3 -3 8
  term: t10 SShape 1 9
  term: t11 ZShape 1 9
  term: t12 PiShape 1 3 6 9
  term: t13 Ramp 0 10
  term: t14 Cosine 5 4
  term: t15 Concave 5 8
  term: t16 Spike 5 2
  term: t17 Binary 5 inf
  term: t18 Discrete 0 0 5 1 10 0
InputVariable: b
  range: -1 1
  term: lo Ramp 1 -1
  term: hi Ramp -1 1
OutputVariable: m
  range: 0 1
  aggregation: Maximum
  defuzzifier: Centroid 100
  default: nan
  lock-previous: true
  term: low Triangle 0 0.25 0.5
  term: high Triangle 0.5 0.75 1
OutputVariable: w
  range: -10 10
  aggregation: none
  defuzzifier: WeightedAverage TakagiSugeno
  default: 0
  term: c Constant 1.5
  term: l Linear 0.5 -2 1
  term: f Function a * sin(b) + max(x, m)
RuleBlock: one
  conjunction: Minimum
  disjunction: AlgebraicSum
  implication: AlgebraicProduct
  activation: Highest 2
  rule: if a is very t1 and b is lo then m is low
  rule: if (a is not t5 or a is somewhat t12) and b is hi then m is high with 0.5
  rule: if a is seldom t18 or b is extremely lo then m is high and w is c
  rule: if m is high then w is f
RuleBlock: two
  conjunction: HamacherProduct
  disjunction: NilpotentMaximum
  implication: Minimum
  activation: Threshold > 0.1
  rule: if a is any then w is l
  rule: if a is t7 and b is any then m is low
";

const FCL: &str = "FUNCTION_BLOCK f
VAR_INPUT
  a: REAL;
END_VAR
VAR_OUTPUT
  y: REAL;
END_VAR
FUZZIFY a
  RANGE := (0 .. 1);
  TERM lo := Triangle 0 0.25 0.5;
  TERM hi := (0.5, 0) (0.75, 1) (1, 0);
END_FUZZIFY
DEFUZZIFY y
  RANGE := (0 .. 1);
  TERM s := 0.2;
  TERM l := Linear 1 0;
  METHOD : COGS;
  DEFAULT := nan | NC;
  LOCK : RANGE;
END_DEFUZZIFY
RULEBLOCK
  AND : MIN;
  OR : MAX;
  RULE 1 : if a is lo then y is s
  RULE 2 : if a is hi or a is not lo then y is l
END_RULEBLOCK
END_FUNCTION_BLOCK
";

const POOL: &[&str] = &[
    "nan",
    "inf",
    "-inf",
    "0",
    "-0",
    "1e308",
    "-1e-320",
    "1",
    "0.5",
    "x",
    "a",
    "b",
    "m",
    "w",
    "is",
    "and",
    "or",
    "then",
    "if",
    "with",
    "very",
    "any",
    "not",
    "(",
    ")",
    ",",
    ":",
    ":=",
    "..",
    "|",
    "#",
    "term:",
    "rule:",
    "range:",
    "Triangle",
    "Discrete",
    "Function",
    "Linear",
    "Constant",
    "Centroid",
    "WeightedSum",
    "Bisector 0",
    "Bisector 99999999999",
    "MeanOfMaximum",
    "General",
    "First 0 2",
    "Lowest",
    "none",
    "",
    "  ",
    "\t",
    "TERM",
    "RULE",
    "END_VAR",
    "sin(",
    "((((((",
    "))))",
    "pow(1)",
    "^",
    "-",
    "~",
    "!",
    "FUNCTION_BLOCK",
    "END_FUNCTION_BLOCK",
];

fn mutate(text: &str, ops: &[(u8, usize, usize)]) -> String {
    let mut words: Vec<String> = text.split(' ').map(str::to_string).collect();
    for &(kind, at, pick) in ops {
        let n = words.len().max(1);
        let i = at % n;
        let token = POOL[pick % POOL.len()].to_string();
        match kind % 4 {
            0 if !words.is_empty() => words[i] = token,
            1 => words.insert(i.min(words.len()), token),
            2 if !words.is_empty() => {
                words.remove(i);
            }
            _ => {
                let w = words.get(i).cloned().unwrap_or_default();
                words.insert(i.min(words.len()), w);
            }
        }
    }
    words.join(" ")
}

fn exercise(engine: &mut stripe3d_fuzzy::Engine, values: &[f64]) {
    for (k, v) in values.iter().enumerate() {
        engine.set_input(k % engine.inputs.len().max(1), *v);
        let _ = engine.process();
        for o in 0..engine.outputs.len() {
            let _ = engine.output_value(o);
        }
    }
}

#[test]
fn the_seed_engines_load() {
    let mut e = fll::read(FLL).expect("FLL seed loads");
    exercise(&mut e, &[0.0, 5.0, 10.0, -3.0, f64::NAN, 0.5]);
    let back = fll::read(&fll::write(&e)).expect("round trip");
    assert!(back == e);
    let mut f = fcl::read(FCL).expect("FCL seed loads");
    exercise(&mut f, &[0.1, 0.9, f64::INFINITY]);
}

proptest! {
    // 400 cases per property by default; set PROPTEST_CASES for a longer hunt.
    #![proptest_config(ProptestConfig { cases: std::env::var("PROPTEST_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(400), ..ProptestConfig::default() })]

    #[test]
    fn arbitrary_text_never_panics(text in "\\PC{0,400}") {
        let _ = fll::read(&text);
        let _ = fcl::read(&text);
        let _ = fld::parse(&text);
        let _ = expr::parse(&text, &|_| None);
    }

    #[test]
    fn mutated_fll_never_panics(ops in prop::collection::vec((any::<u8>(), any::<usize>(), any::<usize>()), 1..6),
                                values in prop::collection::vec(prop_oneof![any::<f64>(), -20.0..20.0f64], 1..8)) {
        if let Ok(mut e) = fll::read(&mutate(FLL, &ops)) {
            exercise(&mut e, &values);
            let _ = fll::read(&fll::write(&e));
        }
    }

    #[test]
    fn mutated_fcl_never_panics(ops in prop::collection::vec((any::<u8>(), any::<usize>(), any::<usize>()), 1..6),
                                values in prop::collection::vec(any::<f64>(), 1..4)) {
        if let Ok(mut e) = fcl::read(&mutate(FCL, &ops)) {
            exercise(&mut e, &values);
        }
    }

    #[test]
    fn formulas_from_tokens_never_panic(toks in prop::collection::vec(0usize..POOL.len(), 0..20), x in any::<f64>()) {
        let text: Vec<&str> = toks.iter().map(|&i| POOL[i]).collect();
        let resolve = |n: &str| (n == "a").then_some(expr::VarRef::Input(0));
        if let Ok(e) = expr::parse(&text.join(" "), &resolve) {
            let _ = e.eval(&[x], &[], x);
        }
    }
}
