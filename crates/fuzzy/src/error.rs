//! Errors of the fuzzy engine.

use thiserror::Error;

/// What building, reading or evaluating an engine can go wrong with.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum FuzzyError {
    /// A text (FLL, FCL, rule, formula) is malformed; `line` is 1-based (0 when not from a file).
    #[error("line {line}: {message}")]
    Syntax {
        /// 1-based line in the source text, 0 when the text did not come from a file.
        line: usize,
        /// What is wrong, naming the offending token.
        message: String,
    },
    /// The engine is structurally incomplete or inconsistent.
    #[error("{0}")]
    Invalid(String),
}

impl FuzzyError {
    /// A syntax error at `line`.
    pub fn syntax(line: usize, message: impl Into<String>) -> Self {
        Self::Syntax {
            line,
            message: message.into(),
        }
    }

    /// The same error placed at `line` (when it was raised without one).
    pub fn at_line(self, line: usize) -> Self {
        match self {
            Self::Syntax { line: 0, message } => Self::Syntax { line, message },
            other => other,
        }
    }
}
