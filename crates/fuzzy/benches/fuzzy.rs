//! Evaluations per second of a small Mamdani engine and a small Takagi-Sugeno engine.
//! Run with `cargo bench -p stripe3d-fuzzy`.

use stripe3d_fuzzy::fll;

fn main() {
    divan::main();
}

/// fuzzylite's SimpleDimmer: 1 input, 3 triangles, 3 rules, Centroid over 200 points.
const MAMDANI: &str = "Engine: SimpleDimmer
InputVariable: Ambient
  range: 0 1
  term: DARK Triangle 0 0.25 0.5
  term: MEDIUM Triangle 0.25 0.5 0.75
  term: BRIGHT Triangle 0.5 0.75 1
OutputVariable: Power
  range: 0 1
  aggregation: Maximum
  defuzzifier: Centroid 200
  default: nan
  term: LOW Triangle 0 0.25 0.5
  term: MEDIUM Triangle 0.25 0.5 0.75
  term: HIGH Triangle 0.5 0.75 1
RuleBlock:
  implication: Minimum
  rule: if Ambient is DARK then Power is HIGH
  rule: if Ambient is MEDIUM then Power is MEDIUM
  rule: if Ambient is BRIGHT then Power is LOW
";

/// A two-input Takagi-Sugeno engine: 4 rules with linear consequents, weighted average.
const TSK: &str = "Engine: tsk
InputVariable: a
  range: 0 1
  term: lo Ramp 1 0
  term: hi Ramp 0 1
InputVariable: b
  range: 0 1
  term: lo Gaussian 0 0.3
  term: hi Gaussian 1 0.3
OutputVariable: y
  range: -10 10
  aggregation: none
  defuzzifier: WeightedAverage TakagiSugeno
  default: nan
  term: l1 Linear 1 2 0
  term: l2 Linear -1 0.5 1
  term: l3 Linear 0.3 -2 2
  term: l4 Constant 4
RuleBlock:
  conjunction: AlgebraicProduct
  rule: if a is lo and b is lo then y is l1
  rule: if a is lo and b is hi then y is l2
  rule: if a is hi and b is lo then y is l3
  rule: if a is hi and b is hi then y is l4
";

#[divan::bench]
fn mamdani_centroid_200(bencher: divan::Bencher) {
    let mut e = fll::read(MAMDANI).expect("engine");
    let mut x = 0.0f64;
    bencher.bench_local(|| {
        x = (x + 0.0137) % 1.0;
        e.set_input(0, x);
        let _ = e.process();
        divan::black_box(e.output_value(0))
    });
}

#[divan::bench]
fn takagi_sugeno_4_rules(bencher: divan::Bencher) {
    let mut e = fll::read(TSK).expect("engine");
    let mut x = 0.0f64;
    bencher.bench_local(|| {
        x = (x + 0.0137) % 1.0;
        e.set_input(0, x);
        e.set_input(1, 1.0 - x);
        let _ = e.process();
        divan::black_box(e.output_value(0))
    });
}
