//! fuzzylite Language (FLL): reader and writer.
//!
//! The reader accepts what fuzzylite's `FllImporter` accepts (including the obsolete `accumulation:` and
//! `lock-valid:` keys) but is stricter where fuzzylite would silently drop something: an unknown key, term class,
//! wrong parameter count, or a rule naming an unknown variable or term is an error naming the line. The writer
//! prints every number in its shortest exact form, so `read(write(e)) == e`.

use crate::engine::{
    Activation, Defuzzifier, Engine, InputVariable, OutputVariable, Rule, RuleBlock,
};
use crate::error::FuzzyError;
use crate::expr::parse_number;
use crate::ops::{SNorm, TNorm};
use crate::term::{Shape, Term, fmt_num};
use std::fmt::Write as _;

/// Largest FLL text accepted, bytes.
pub const MAX_FLL_BYTES: usize = 4 << 20;

enum Section {
    None,
    Input(InputVariable),
    Output(OutputVariable),
    Block(RuleBlock),
}

fn boolean(v: &str, line: usize) -> Result<bool, FuzzyError> {
    match v {
        "true" => Ok(true),
        "false" => Ok(false),
        other => Err(FuzzyError::syntax(
            line,
            format!("expected true or false, found '{other}'"),
        )),
    }
}

fn range(v: &str, line: usize) -> Result<(f64, f64), FuzzyError> {
    let t: Vec<&str> = v.split_whitespace().collect();
    if t.len() != 2 {
        return Err(FuzzyError::syntax(
            line,
            format!("range needs two numbers, found '{v}'"),
        ));
    }
    let n = |s: &str| {
        parse_number(s)
            .ok_or_else(|| FuzzyError::syntax(line, format!("range: '{s}' is not a number")))
    };
    Ok((n(t[0])?, n(t[1])?))
}

fn term(v: &str, line: usize) -> Result<Term, FuzzyError> {
    let mut it = v.splitn(3, char::is_whitespace);
    let name = it.next().unwrap_or("").trim();
    let rest = it.next().unwrap_or("").trim();
    if name.is_empty() || rest.is_empty() {
        return Err(FuzzyError::syntax(
            line,
            format!("expected 'term: NAME CLASS PARAMETERS', found '{v}'"),
        ));
    }
    let params = it.next().unwrap_or("");
    let shape = Shape::configure(rest, params).map_err(|e| e.at_line(line))?;
    Ok(Term {
        name: name.to_string(),
        shape,
    })
}

fn tnorm(v: &str, line: usize) -> Result<Option<TNorm>, FuzzyError> {
    if v == "none" || v.is_empty() {
        return Ok(None);
    }
    TNorm::from_name(v)
        .map(Some)
        .ok_or_else(|| FuzzyError::syntax(line, format!("unknown T-norm '{v}'")))
}

fn snorm(v: &str, line: usize) -> Result<Option<SNorm>, FuzzyError> {
    if v == "none" || v.is_empty() {
        return Ok(None);
    }
    SNorm::from_name(v)
        .map(Some)
        .ok_or_else(|| FuzzyError::syntax(line, format!("unknown S-norm '{v}'")))
}

fn defuzzifier(v: &str, line: usize) -> Result<Option<Defuzzifier>, FuzzyError> {
    let t: Vec<&str> = v.split_whitespace().collect();
    match t.as_slice() {
        [] | ["none"] => Ok(None),
        [name] => Defuzzifier::from_name(name, None)
            .map(Some)
            .map_err(|e| e.at_line(line)),
        [name, p] => Defuzzifier::from_name(name, Some(p))
            .map(Some)
            .map_err(|e| e.at_line(line)),
        _ => Err(FuzzyError::syntax(
            line,
            format!("defuzzifier takes a name and one parameter, found '{v}'"),
        )),
    }
}

/// Reads an engine from FLL text and loads it.
pub fn read(text: &str) -> Result<Engine, FuzzyError> {
    if text.len() > MAX_FLL_BYTES {
        return Err(FuzzyError::syntax(
            0,
            format!(
                "{} bytes is more than the {MAX_FLL_BYTES} accepted",
                text.len()
            ),
        ));
    }
    let mut engine = Engine::new("");
    let mut section = Section::None;
    let finish = |s: Section, e: &mut Engine| match s {
        Section::None => {}
        Section::Input(v) => e.inputs.push(v),
        Section::Output(v) => e.outputs.push(v),
        Section::Block(b) => e.blocks.push(b),
    };
    for (n, raw) in text.lines().enumerate() {
        let line = n + 1;
        let content = raw.split('#').next().unwrap_or("").trim();
        if content.is_empty() {
            continue;
        }
        let Some((key, value)) = content.split_once(':') else {
            return Err(FuzzyError::syntax(
                line,
                format!("expected 'key: value', found '{content}'"),
            ));
        };
        let (key, value) = (key.trim(), value.trim());
        match key {
            "Engine" => {
                engine.name = value.to_string();
                continue;
            }
            "InputVariable" | "OutputVariable" | "RuleBlock" => {
                finish(std::mem::replace(&mut section, Section::None), &mut engine);
                section = match key {
                    "InputVariable" => Section::Input(InputVariable::new(value.to_string())),
                    "OutputVariable" => Section::Output(OutputVariable::new(value.to_string())),
                    _ => Section::Block(RuleBlock::new(value.to_string())),
                };
                continue;
            }
            _ => {}
        }
        let unknown = || FuzzyError::syntax(line, format!("key '{key}' is not known here"));
        match &mut section {
            Section::None => match key {
                "description" => engine.description = value.to_string(),
                _ => {
                    return Err(FuzzyError::syntax(
                        line,
                        format!("'{key}' outside of a variable or rule block"),
                    ));
                }
            },
            Section::Input(v) => match key {
                "description" => v.description = value.to_string(),
                "enabled" => v.enabled = boolean(value, line)?,
                "range" => (v.minimum, v.maximum) = range(value, line)?,
                "lock-range" => v.lock_range = boolean(value, line)?,
                "term" => v.terms.push(term(value, line)?),
                _ => return Err(unknown()),
            },
            Section::Output(v) => match key {
                "description" => v.description = value.to_string(),
                "enabled" => v.enabled = boolean(value, line)?,
                "range" => (v.minimum, v.maximum) = range(value, line)?,
                "lock-range" => v.lock_range = boolean(value, line)?,
                "aggregation" | "accumulation" => v.aggregation = snorm(value, line)?,
                "defuzzifier" => v.defuzzifier = defuzzifier(value, line)?,
                "default" => {
                    v.default = parse_number(value).ok_or_else(|| {
                        FuzzyError::syntax(line, format!("default '{value}' is not a number"))
                    })?
                }
                "lock-previous" | "lock-valid" => v.lock_previous = boolean(value, line)?,
                "term" => v.terms.push(term(value, line)?),
                _ => return Err(unknown()),
            },
            Section::Block(b) => match key {
                "description" => b.description = value.to_string(),
                "enabled" => b.enabled = boolean(value, line)?,
                "conjunction" => b.conjunction = tnorm(value, line)?,
                "disjunction" => b.disjunction = snorm(value, line)?,
                "implication" => b.implication = tnorm(value, line)?,
                "activation" => {
                    if value == "none" {
                        b.activation = None;
                    } else if let Some(t) = TNorm::from_name(value) {
                        // fuzzylite 5 wrote the implication operator under this key.
                        b.implication = Some(t);
                    } else {
                        b.activation =
                            Some(Activation::from_fll(value).map_err(|e| e.at_line(line))?);
                    }
                }
                "rule" => b.rules.push(Rule::new(value, line)),
                _ => return Err(unknown()),
            },
        }
    }
    finish(section, &mut engine);
    engine.load()?;
    Ok(engine)
}

/// Writes an engine as FLL.
pub fn write(engine: &Engine) -> String {
    let mut s = String::new();
    let b = |v: bool| if v { "true" } else { "false" };
    let _ = writeln!(s, "Engine: {}", engine.name);
    if !engine.description.is_empty() {
        let _ = writeln!(s, "description: {}", engine.description);
    }
    let term_line = |s: &mut String, t: &Term| {
        let p = t.shape.parameters();
        if p.is_empty() {
            let _ = writeln!(s, "  term: {} {}", t.name, t.shape.class());
        } else {
            let _ = writeln!(s, "  term: {} {} {}", t.name, t.shape.class(), p);
        }
    };
    for v in &engine.inputs {
        let _ = writeln!(s, "InputVariable: {}", v.name);
        if !v.description.is_empty() {
            let _ = writeln!(s, "  description: {}", v.description);
        }
        let _ = writeln!(s, "  enabled: {}", b(v.enabled));
        let _ = writeln!(s, "  range: {} {}", fmt_num(v.minimum), fmt_num(v.maximum));
        let _ = writeln!(s, "  lock-range: {}", b(v.lock_range));
        v.terms.iter().for_each(|t| term_line(&mut s, t));
    }
    for v in &engine.outputs {
        let _ = writeln!(s, "OutputVariable: {}", v.name);
        if !v.description.is_empty() {
            let _ = writeln!(s, "  description: {}", v.description);
        }
        let _ = writeln!(s, "  enabled: {}", b(v.enabled));
        let _ = writeln!(s, "  range: {} {}", fmt_num(v.minimum), fmt_num(v.maximum));
        let _ = writeln!(s, "  lock-range: {}", b(v.lock_range));
        let _ = writeln!(
            s,
            "  aggregation: {}",
            v.aggregation.map_or("none", |a| a.name())
        );
        match &v.defuzzifier {
            None => {
                let _ = writeln!(s, "  defuzzifier: none");
            }
            Some(d) => {
                let _ = writeln!(s, "  defuzzifier: {} {}", d.name(), d.parameter());
            }
        }
        let _ = writeln!(s, "  default: {}", fmt_num(v.default));
        let _ = writeln!(s, "  lock-previous: {}", b(v.lock_previous));
        v.terms.iter().for_each(|t| term_line(&mut s, t));
    }
    for blk in &engine.blocks {
        let _ = writeln!(s, "RuleBlock: {}", blk.name);
        if !blk.description.is_empty() {
            let _ = writeln!(s, "  description: {}", blk.description);
        }
        let _ = writeln!(s, "  enabled: {}", b(blk.enabled));
        let _ = writeln!(
            s,
            "  conjunction: {}",
            blk.conjunction.map_or("none", |t| t.name())
        );
        let _ = writeln!(
            s,
            "  disjunction: {}",
            blk.disjunction.map_or("none", |t| t.name())
        );
        let _ = writeln!(
            s,
            "  implication: {}",
            blk.implication.map_or("none", |t| t.name())
        );
        let _ = writeln!(
            s,
            "  activation: {}",
            blk.activation.map_or("none".to_string(), |a| a.to_fll())
        );
        for r in &blk.rules {
            let _ = writeln!(s, "  rule: {}", r.text);
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    const DIMMER: &str = "Engine: SimpleDimmer
InputVariable: Ambient
  enabled: true
  range: 0.000 1.000
  lock-range: false
  term: DARK Triangle 0.000 0.250 0.500
  term: MEDIUM Triangle 0.250 0.500 0.750
  term: BRIGHT Triangle 0.500 0.750 1.000
OutputVariable: Power
  enabled: true
  range: 0.000 1.000
  lock-range: false
  aggregation: Maximum
  defuzzifier: Centroid 200
  default: nan
  lock-previous: false
  term: LOW Triangle 0.000 0.250 0.500
  term: MEDIUM Triangle 0.250 0.500 0.750
  term: HIGH Triangle 0.500 0.750 1.000
RuleBlock: 
  enabled: true
  conjunction: none
  disjunction: none
  implication: Minimum
  activation: General
  rule: if Ambient is DARK then Power is HIGH
  rule: if Ambient is MEDIUM then Power is MEDIUM
  rule: if Ambient is BRIGHT then Power is LOW
";

    #[test]
    fn reads_evaluates_and_round_trips() {
        let mut e = read(DIMMER).expect("reads");
        // Values fuzzylite 6 computes for this engine (SimpleDimmer.fld).
        for (x, y) in [(0.0, f64::NAN), (0.25, 0.75), (0.5, 0.5), (0.375, 0.625)] {
            e.set_input(0, x);
            e.process().expect("process");
            let got = e.output_value(0);
            assert!(
                (got.is_nan() && y.is_nan()) || (got - y).abs() < 1e-3,
                "x={x}: {got} vs {y}"
            );
        }
        let text = write(&e);
        let again = read(&text).expect("round trip");
        assert_eq!(again, e);
        assert_eq!(write(&again), text);
    }

    #[test]
    fn errors_name_the_line() {
        let cases = [
            (
                DIMMER.replace(
                    "Triangle 0.000 0.250 0.500\n  term: MEDIUM",
                    "Blob 0.000 0.250 0.500\n  term: MEDIUM",
                ),
                6,
            ),
            (
                DIMMER.replace(
                    "DARK Triangle 0.000 0.250 0.500",
                    "DARK Triangle 0.000 0.250",
                ),
                6,
            ),
            (
                DIMMER.replace("then Power is HIGH", "then Power is HUGE"),
                26,
            ),
            (DIMMER.replace("if Ambient is DARK", "if Light is DARK"), 26),
            (
                DIMMER.replace(
                    "  enabled: true\n  range: 0.000 1.000\n  lock-range: false\n  aggregation",
                    "  enabled: yes\n  range: 0.000 1.000\n  lock-range: false\n  aggregation",
                ),
                10,
            ),
            (
                DIMMER.replace("aggregation: Maximum", "aggregation: Maxi"),
                13,
            ),
            (
                DIMMER.replace("  lock-previous: false", "  colour: red"),
                16,
            ),
            (DIMMER.replace("Centroid 200", "Centroid -3"), 14),
        ];
        for (text, line) in cases {
            match read(&text) {
                Err(FuzzyError::Syntax { line: l, message }) => assert_eq!(l, line, "{message}"),
                other => panic!("expected a syntax error at line {line}, got {other:?}"),
            }
        }
        assert!(
            read(
                "Engine: x\nInputVariable: a\nOutputVariable: a\n  defuzzifier: WeightedAverage\n"
            )
            .is_err()
        );
        assert!(read(&DIMMER.replace("implication: Minimum", "implication: none")).is_err());
    }
}
