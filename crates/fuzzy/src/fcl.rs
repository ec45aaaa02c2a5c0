//! IEC 61131-7 Fuzzy Control Language (FCL) reader, with fuzzylite's extensions (its term classes, `COGS`,
//! `DEFAULT := v | NC`, `LOCK : PREVIOUS | RANGE`).
//!
//! Mapping as fuzzylite's `FclImporter`: `AND`/`OR`/`ACT`/`ACCU` name norms by IEC abbreviation (`MIN`, `PROD`,
//! `BDIF`, `DPROD`, `EPROD`, `HPROD`, `NMIN`; `MAX`, `ASUM`, `BSUM`, `NSUM`, `DSUM`, `ESUM`, `HSUM`, `NMAX`) or by
//! class name; `METHOD` is `COG` (Centroid), `COA` (Bisector), `LM` (SmallestOfMaximum), `RM`
//! (LargestOfMaximum), `MM` (MeanOfMaximum), `COGS` (WeightedAverage) or `COGSS` (WeightedSum). FCL carries no
//! resolution: integral defuzzifiers read from FCL sample [`FCL_RESOLUTION`] points unless
//! [`read_with_resolution`] says otherwise. Comments: `//`, `#`, `(* ... *)` on one line, and lines starting
//! with `%`.

use crate::engine::{
    Activation, Defuzzifier, Engine, InputVariable, OutputVariable, Rule, RuleBlock,
};
use crate::error::FuzzyError;
use crate::expr::parse_number;
use crate::ops::{SNorm, TNorm};
use crate::term::{Shape, Term};

/// Resolution of integral defuzzifiers read from FCL: 500 points, the finest fuzzylite's own example engines use
/// (they use 100 to 500). With it every example engine matches fuzzylite from its FCL as from its FLL; with
/// fuzzylite 7's default of 1000, AllTerms and Laundry differ by 1.3e-3 and 1.9e-3 (relative) from tables
/// computed at 200 and 500 points.
pub const FCL_RESOLUTION: usize = 500;

/// Largest FCL text accepted, bytes.
pub const MAX_FCL_BYTES: usize = 4 << 20;

fn tnorm(v: &str, line: usize) -> Result<Option<TNorm>, FuzzyError> {
    Ok(Some(match v {
        "NONE" | "none" => return Ok(None),
        "MIN" => TNorm::Minimum,
        "PROD" => TNorm::AlgebraicProduct,
        "BDIF" => TNorm::BoundedDifference,
        "DPROD" => TNorm::DrasticProduct,
        "EPROD" => TNorm::EinsteinProduct,
        "HPROD" => TNorm::HamacherProduct,
        "NMIN" => TNorm::NilpotentMinimum,
        other => TNorm::from_name(other)
            .ok_or_else(|| FuzzyError::syntax(line, format!("unknown T-norm '{other}'")))?,
    }))
}

fn snorm(v: &str, line: usize) -> Result<Option<SNorm>, FuzzyError> {
    Ok(Some(match v {
        "NONE" | "none" => return Ok(None),
        "MAX" => SNorm::Maximum,
        "ASUM" => SNorm::AlgebraicSum,
        "BSUM" => SNorm::BoundedSum,
        "NSUM" => SNorm::NormalizedSum,
        "DSUM" => SNorm::DrasticSum,
        "ESUM" => SNorm::EinsteinSum,
        "HSUM" => SNorm::HamacherSum,
        "NMAX" => SNorm::NilpotentMaximum,
        "USUM" => SNorm::UnboundedSum,
        other => SNorm::from_name(other)
            .ok_or_else(|| FuzzyError::syntax(line, format!("unknown S-norm '{other}'")))?,
    }))
}

fn value_after<'a>(line: &'a str, sep: &str, lno: usize) -> Result<&'a str, FuzzyError> {
    line.split_once(sep)
        .map(|(_, v)| v.trim())
        .ok_or_else(|| FuzzyError::syntax(lno, format!("expected '{sep}' in '{line}'")))
}

fn parse_range(line: &str, lno: usize) -> Result<(f64, f64), FuzzyError> {
    let v: String = value_after(line, ":=", lno)?
        .chars()
        .filter(|c| !matches!(c, '(' | ')' | ' ' | '\t'))
        .collect();
    let (a, b) = v.split_once("..").ok_or_else(|| {
        FuzzyError::syntax(
            lno,
            format!("expected RANGE := (start .. end), found '{line}'"),
        )
    })?;
    let n = |s: &str| {
        parse_number(s).ok_or_else(|| FuzzyError::syntax(lno, format!("'{s}' is not a number")))
    };
    Ok((n(a)?, n(b)?))
}

fn parse_term(line: &str, lno: usize) -> Result<Term, FuzzyError> {
    let rest = line
        .trim_start()
        .strip_prefix("TERM")
        .unwrap_or(line)
        .trim();
    let (name, def) = rest.split_once(":=").ok_or_else(|| {
        FuzzyError::syntax(
            lno,
            format!("expected TERM name := definition, found '{line}'"),
        )
    })?;
    let name = name.trim();
    let def = def.trim();
    if name.is_empty() || def.is_empty() {
        return Err(FuzzyError::syntax(lno, format!("malformed term '{line}'")));
    }
    let shape = if def.starts_with('(') {
        // Points (x, y) (x, y) ... form a Discrete term.
        let flat: String = def
            .chars()
            .map(|c| if matches!(c, '(' | ')' | ',') { ' ' } else { c })
            .collect();
        Shape::configure("Discrete", &flat)
    } else if parse_number(def.split_whitespace().next().unwrap_or("")).is_some() {
        Shape::configure("Constant", def)
    } else {
        let (class, params) = def.split_once(char::is_whitespace).unwrap_or((def, ""));
        Shape::configure(class, params)
    }
    .map_err(|e| e.at_line(lno))?;
    Ok(Term {
        name: name.to_string(),
        shape,
    })
}

fn strip_comments(raw: &str) -> String {
    let mut s = raw
        .split("//")
        .next()
        .unwrap_or("")
        .split('#')
        .next()
        .unwrap_or("")
        .to_string();
    while let Some(a) = s.find("(*") {
        match s[a..].find("*)") {
            Some(b) => s.replace_range(a..a + b + 2, " "),
            None => s.truncate(a),
        }
    }
    s.replace(';', "").trim().to_string()
}

/// Reads an engine from FCL text and loads it.
pub fn read(text: &str) -> Result<Engine, FuzzyError> {
    read_with_resolution(text, FCL_RESOLUTION)
}

/// Reads an engine from FCL text with the given resolution for integral defuzzifiers, and loads it.
pub fn read_with_resolution(text: &str, resolution: usize) -> Result<Engine, FuzzyError> {
    let resolution = resolution.to_string();
    if text.len() > MAX_FCL_BYTES {
        return Err(FuzzyError::syntax(
            0,
            format!(
                "{} bytes is more than the {MAX_FCL_BYTES} accepted",
                text.len()
            ),
        ));
    }
    let mut engine = Engine::new("");
    #[derive(PartialEq)]
    enum Block {
        None,
        VarInput,
        VarOutput,
        Fuzzify(usize),
        Defuzzify(usize),
        Rules(usize),
    }
    let mut block = Block::None;
    for (n, raw) in text.lines().enumerate() {
        let lno = n + 1;
        let line = strip_comments(raw);
        if line.is_empty() || line.starts_with('%') {
            continue;
        }
        let first = line.split_whitespace().next().unwrap_or("");
        let rest = line[first.len()..].trim();
        let closes = |b: &Block| match b {
            Block::VarInput | Block::VarOutput => "END_VAR",
            Block::Fuzzify(_) => "END_FUZZIFY",
            Block::Defuzzify(_) => "END_DEFUZZIFY",
            Block::Rules(_) => "END_RULEBLOCK",
            Block::None => "",
        };
        if block == Block::None {
            match first {
                "FUNCTION_BLOCK" => engine.name = rest.to_string(),
                "END_FUNCTION_BLOCK" => break,
                "VAR_INPUT" => block = Block::VarInput,
                "VAR_OUTPUT" => block = Block::VarOutput,
                "FUZZIFY" => {
                    let i = engine.input_index(rest).ok_or_else(|| {
                        FuzzyError::syntax(
                            lno,
                            format!("FUZZIFY {rest}: no such input in VAR_INPUT"),
                        )
                    })?;
                    block = Block::Fuzzify(i);
                }
                "DEFUZZIFY" => {
                    let k = engine.output_index(rest).ok_or_else(|| {
                        FuzzyError::syntax(
                            lno,
                            format!("DEFUZZIFY {rest}: no such output in VAR_OUTPUT"),
                        )
                    })?;
                    block = Block::Defuzzify(k);
                }
                "RULEBLOCK" => {
                    engine.blocks.push(RuleBlock {
                        activation: Some(Activation::General),
                        ..RuleBlock::new(rest)
                    });
                    block = Block::Rules(engine.blocks.len() - 1);
                }
                other => return Err(FuzzyError::syntax(lno, format!("unknown block '{other}'"))),
            }
            continue;
        }
        if first == closes(&block) {
            block = Block::None;
            continue;
        }
        if matches!(
            first,
            "VAR_INPUT"
                | "VAR_OUTPUT"
                | "FUZZIFY"
                | "DEFUZZIFY"
                | "RULEBLOCK"
                | "END_FUNCTION_BLOCK"
        ) {
            return Err(FuzzyError::syntax(
                lno,
                format!("expected {} before '{first}'", closes(&block)),
            ));
        }
        match block {
            Block::VarInput | Block::VarOutput => {
                let (name, _ty) = line.split_once(':').ok_or_else(|| {
                    FuzzyError::syntax(lno, format!("expected 'name : REAL', found '{line}'"))
                })?;
                let name = name.trim().to_string();
                if block == Block::VarInput {
                    engine.inputs.push(InputVariable::new(name));
                } else {
                    engine.outputs.push(OutputVariable::new(name));
                }
            }
            Block::Fuzzify(i) => {
                let v = &mut engine.inputs[i];
                match first {
                    "RANGE" => (v.minimum, v.maximum) = parse_range(&line, lno)?,
                    "TERM" => v.terms.push(parse_term(&line, lno)?),
                    "ENABLED" => v.enabled = enabled(&line, lno)?,
                    other => {
                        return Err(FuzzyError::syntax(
                            lno,
                            format!("unexpected '{other}' in FUZZIFY"),
                        ));
                    }
                }
            }
            Block::Defuzzify(k) => {
                let v = &mut engine.outputs[k];
                match first {
                    "RANGE" => (v.minimum, v.maximum) = parse_range(&line, lno)?,
                    "TERM" => v.terms.push(parse_term(&line, lno)?),
                    "ENABLED" => v.enabled = enabled(&line, lno)?,
                    "METHOD" => {
                        let m = value_after(&line, ":", lno)?;
                        let class = match m {
                            "COG" => "Centroid",
                            "COA" => "Bisector",
                            "LM" => "SmallestOfMaximum",
                            "RM" => "LargestOfMaximum",
                            "MM" => "MeanOfMaximum",
                            "COGS" => "WeightedAverage",
                            "COGSS" => "WeightedSum",
                            other => other,
                        };
                        v.defuzzifier = if class == "NONE" {
                            None
                        } else {
                            let integral = Defuzzifier::from_name(class, None)
                                .map_err(|e| e.at_line(lno))?
                                .is_integral();
                            let param = integral.then_some(resolution.as_str());
                            Some(Defuzzifier::from_name(class, param).map_err(|e| e.at_line(lno))?)
                        };
                    }
                    "ACCU" => v.aggregation = snorm(value_after(&line, ":", lno)?, lno)?,
                    "DEFAULT" => {
                        let val = value_after(&line, ":=", lno)?;
                        let (num, nc) = match val.split_once('|') {
                            Some((a, b)) => (a.trim(), Some(b.trim())),
                            None => (val, None),
                        };
                        v.default = parse_number(num).ok_or_else(|| {
                            FuzzyError::syntax(lno, format!("DEFAULT: '{num}' is not a number"))
                        })?;
                        match nc {
                            None => {}
                            Some("NC") => v.lock_previous = true,
                            Some(other) => {
                                return Err(FuzzyError::syntax(
                                    lno,
                                    format!("expected NC after '|', found '{other}'"),
                                ));
                            }
                        }
                    }
                    "LOCK" => {
                        let flags: Vec<&str> = value_after(&line, ":", lno)?
                            .split('|')
                            .map(str::trim)
                            .collect();
                        if flags.is_empty()
                            || flags.len() > 2
                            || flags.iter().any(|f| !matches!(*f, "PREVIOUS" | "RANGE"))
                        {
                            return Err(FuzzyError::syntax(
                                lno,
                                format!("expected LOCK : PREVIOUS | RANGE, found '{line}'"),
                            ));
                        }
                        v.lock_previous = flags.contains(&"PREVIOUS");
                        v.lock_range = flags.contains(&"RANGE");
                    }
                    other => {
                        return Err(FuzzyError::syntax(
                            lno,
                            format!("unexpected '{other}' in DEFUZZIFY"),
                        ));
                    }
                }
            }
            Block::Rules(b) => {
                let blk = &mut engine.blocks[b];
                match first {
                    "AND" => blk.conjunction = tnorm(value_after(&line, ":", lno)?, lno)?,
                    "OR" => blk.disjunction = snorm(value_after(&line, ":", lno)?, lno)?,
                    "ACT" => blk.implication = tnorm(value_after(&line, ":", lno)?, lno)?,
                    "ENABLED" => blk.enabled = enabled(&line, lno)?,
                    "RULE" => {
                        let text = line.split_once(':').map_or(rest, |(_, r)| r).trim();
                        blk.rules.push(Rule::new(text, lno));
                    }
                    other => {
                        return Err(FuzzyError::syntax(
                            lno,
                            format!("unexpected '{other}' in RULEBLOCK"),
                        ));
                    }
                }
            }
            Block::None => {}
        }
    }
    if block != Block::None {
        return Err(FuzzyError::syntax(
            text.lines().count(),
            "the text ends inside a block (missing END_...)",
        ));
    }
    engine.load()?;
    Ok(engine)
}

fn enabled(line: &str, lno: usize) -> Result<bool, FuzzyError> {
    match value_after(line, ":", lno)? {
        "TRUE" => Ok(true),
        "FALSE" => Ok(false),
        other => Err(FuzzyError::syntax(
            lno,
            format!("expected TRUE or FALSE, found '{other}'"),
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const DIMMER: &str = "FUNCTION_BLOCK SimpleDimmer
VAR_INPUT
  Ambient: REAL;
END_VAR
VAR_OUTPUT
  Power: REAL;
END_VAR
FUZZIFY Ambient
  RANGE := (0.000 .. 1.000);
  TERM DARK := Triangle 0.000 0.250 0.500;
  TERM MEDIUM := Triangle 0.250 0.500 0.750;
  TERM BRIGHT := (0.5, 0) (0.75, 1) (1, 0);
END_FUZZIFY
DEFUZZIFY Power
  RANGE := (0.000 .. 1.000);
  TERM LOW := Triangle 0.000 0.250 0.500;
  TERM MEDIUM := Triangle 0.250 0.500 0.750;
  TERM HIGH := Triangle 0.500 0.750 1.000;
  METHOD : COG;
  ACCU : MAX;
  DEFAULT := nan;
END_DEFUZZIFY
RULEBLOCK (* the rules *)
  ACT : MIN;
  RULE 1 : if Ambient is DARK then Power is HIGH
  RULE 2 : if Ambient is MEDIUM then Power is MEDIUM
  RULE 3 : if Ambient is BRIGHT then Power is LOW
END_RULEBLOCK
END_FUNCTION_BLOCK
";

    #[test]
    fn reads_the_standard_form() {
        let mut e = read(DIMMER).expect("reads");
        assert_eq!(e.inputs[0].terms[2].shape.class(), "Discrete");
        e.set_input(0, 0.25);
        e.process().expect("process");
        assert!((e.output_value(0) - 0.75).abs() < 1e-3);
    }

    #[test]
    fn errors_name_the_line() {
        for (text, line) in [
            (DIMMER.replace("FUZZIFY Ambient", "FUZZIFY Light"), 8),
            (DIMMER.replace("METHOD : COG", "METHOD : WOW"), 19),
            (DIMMER.replace("Power is HIGH", "Power is HUGE"), 25),
            (DIMMER.replace("END_DEFUZZIFY", "END_FUZZIFY"), 22),
            (
                DIMMER.replace(
                    "RANGE := (0.000 .. 1.000);\n  TERM DARK",
                    "RANGE := (0.000 , 1.000);\n  TERM DARK",
                ),
                9,
            ),
        ] {
            match read(&text) {
                Err(FuzzyError::Syntax { line: l, message }) => assert_eq!(l, line, "{message}"),
                other => panic!("expected a syntax error at line {line}, got {other:?}"),
            }
        }
        assert!(read("FUNCTION_BLOCK x\nVAR_INPUT\n a: REAL;\n").is_err());
    }
}
