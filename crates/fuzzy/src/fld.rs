//! FuzzyLite Dataset (FLD): a header of variable names, then rows of whitespace-separated numbers.

use crate::engine::Engine;
use crate::error::FuzzyError;
use crate::expr::parse_number;
use std::fmt::Write as _;

/// A parsed table: column names and rows (with their 1-based line numbers).
#[derive(Debug, Clone, PartialEq)]
pub struct Table {
    /// Column names.
    pub columns: Vec<String>,
    /// Rows of values, each with its line number.
    pub rows: Vec<(usize, Vec<f64>)>,
}

/// Parses FLD text. Blank lines and lines starting with `#` are skipped.
pub fn parse(text: &str) -> Result<Table, FuzzyError> {
    let mut columns: Option<Vec<String>> = None;
    let mut rows = Vec::new();
    for (n, raw) in text.lines().enumerate() {
        let line = raw.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        match &columns {
            None => columns = Some(line.split_whitespace().map(str::to_string).collect()),
            Some(cols) => {
                let mut row = Vec::with_capacity(cols.len());
                for tok in line.split_whitespace() {
                    row.push(parse_number(tok).ok_or_else(|| {
                        FuzzyError::syntax(n + 1, format!("'{tok}' is not a number"))
                    })?);
                }
                if row.len() != cols.len() {
                    return Err(FuzzyError::syntax(
                        n + 1,
                        format!(
                            "{} values, but the header names {} columns",
                            row.len(),
                            cols.len()
                        ),
                    ));
                }
                rows.push((n + 1, row));
            }
        }
    }
    let columns =
        columns.ok_or_else(|| FuzzyError::syntax(1, "no header line of variable names"))?;
    Ok(Table { columns, rows })
}

/// Formats a value as FLD does: 9 decimals, `nan`, `inf`, `-inf`.
pub fn fmt(v: f64) -> String {
    if v.is_nan() {
        "nan".into()
    } else if v == f64::INFINITY {
        "inf".into()
    } else if v == f64::NEG_INFINITY {
        "-inf".into()
    } else {
        format!("{v:.9}")
    }
}

/// For each row, the column of every input variable of `engine`; an input without a column is an error.
pub fn input_columns(engine: &Engine, table: &Table) -> Result<Vec<usize>, FuzzyError> {
    engine
        .inputs
        .iter()
        .map(|v| {
            table
                .columns
                .iter()
                .position(|c| *c == v.name)
                .ok_or_else(|| {
                    FuzzyError::syntax(
                        1,
                        format!("the header has no column for input variable '{}'", v.name),
                    )
                })
        })
        .collect()
}

/// Evaluates every row in order on `engine` and returns the FLD output: input names then output names, and per
/// row the inputs followed by the outputs.
pub fn evaluate(engine: &mut Engine, text: &str) -> Result<String, FuzzyError> {
    let table = parse(text)?;
    let cols = input_columns(engine, &table)?;
    let mut out = String::new();
    let names: Vec<&str> = engine
        .inputs
        .iter()
        .map(|v| v.name.as_str())
        .chain(engine.outputs.iter().map(|v| v.name.as_str()))
        .collect();
    let _ = writeln!(out, "{}", names.join(" "));
    for (_, row) in &table.rows {
        for (i, &c) in cols.iter().enumerate() {
            engine.set_input(i, row[c]);
        }
        engine.process()?;
        let values: Vec<String> = (0..engine.inputs.len())
            .map(|i| fmt(engine.input_value(i)))
            .chain((0..engine.outputs.len()).map(|k| fmt(engine.output_value(k))))
            .collect();
        let _ = writeln!(out, "{}", values.join(" "));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tables_parse_and_refuse_ragged_rows() {
        let t = parse("a b\n1 2\n\n# note\nnan -inf\n").expect("table");
        assert_eq!(t.columns, vec!["a", "b"]);
        assert_eq!(t.rows.len(), 2);
        assert!(t.rows[1].1[0].is_nan());
        assert!(matches!(
            parse("a b\n1\n"),
            Err(FuzzyError::Syntax { line: 2, .. })
        ));
        assert!(matches!(
            parse("a b\n1 x\n"),
            Err(FuzzyError::Syntax { line: 2, .. })
        ));
        assert!(parse("").is_err());
        assert_eq!(fmt(0.5), "0.500000000");
        assert_eq!(fmt(f64::NAN), "nan");
    }
}
