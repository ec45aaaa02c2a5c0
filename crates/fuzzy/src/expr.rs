//! Arithmetic expressions of `Function` terms: a small precedence-climbing parser and a tree evaluator.
//!
//! Grammar (lowest precedence first): `or`, `and`, `+ -`, `* / %`, unary `- + ! ~`, `^` (right-associative), then
//! numbers, variables, `x`, parenthesised expressions and function calls such as `sin(x)` or `pow(a, 2)`. The
//! functions and operators are fuzzylite's. Unlike fuzzylite, a leading minus (`-x`) is accepted. Nesting is
//! limited to [`MAX_DEPTH`] levels so hostile input cannot exhaust the stack.

use crate::error::FuzzyError;
use crate::ops::{is_eq, is_ge, is_gt, is_le, is_lt, max, min};

/// Deepest nesting of parentheses, calls and unary operators accepted.
pub const MAX_DEPTH: usize = 64;

/// A variable an expression reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VarRef {
    /// Input variable by index.
    Input(usize),
    /// Output variable by index (its current value).
    Output(usize),
    /// The argument `x` of the membership function.
    X,
}

/// One-argument functions.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[allow(missing_docs)]
pub enum Unary {
    Neg,
    Not,
    Acos,
    Asin,
    Atan,
    Ceil,
    Cos,
    Cosh,
    Exp,
    Abs,
    Floor,
    Log,
    Log10,
    Round,
    Sin,
    Sinh,
    Sqrt,
    Tan,
    Tanh,
    Log1p,
    Acosh,
    Asinh,
    Atanh,
}

/// Two-argument functions and operators.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[allow(missing_docs)]
pub enum Binary {
    Add,
    Sub,
    Mul,
    Div,
    Mod,
    Pow,
    And,
    Or,
    Gt,
    Ge,
    Eq,
    Neq,
    Le,
    Lt,
    Min,
    Max,
    Atan2,
    Fmod,
}

/// A parsed expression.
#[derive(Debug, Clone, PartialEq)]
pub enum Expr {
    /// A number.
    Const(f64),
    /// A variable.
    Var(VarRef),
    /// A unary function of a sub-expression.
    Unary(Unary, Box<Expr>),
    /// A binary function of two sub-expressions.
    Binary(Binary, Box<Expr>, Box<Expr>),
}

fn unary_by_name(s: &str) -> Option<Unary> {
    Some(match s {
        "acos" => Unary::Acos,
        "asin" => Unary::Asin,
        "atan" => Unary::Atan,
        "ceil" => Unary::Ceil,
        "cos" => Unary::Cos,
        "cosh" => Unary::Cosh,
        "exp" => Unary::Exp,
        "abs" | "fabs" => Unary::Abs,
        "floor" => Unary::Floor,
        "log" => Unary::Log,
        "log10" => Unary::Log10,
        "round" => Unary::Round,
        "sin" => Unary::Sin,
        "sinh" => Unary::Sinh,
        "sqrt" => Unary::Sqrt,
        "tan" => Unary::Tan,
        "tanh" => Unary::Tanh,
        "log1p" => Unary::Log1p,
        "acosh" => Unary::Acosh,
        "asinh" => Unary::Asinh,
        "atanh" => Unary::Atanh,
        _ => return None,
    })
}

fn binary_fn_by_name(s: &str) -> Option<Binary> {
    Some(match s {
        "gt" => Binary::Gt,
        "ge" => Binary::Ge,
        "eq" => Binary::Eq,
        "neq" => Binary::Neq,
        "le" => Binary::Le,
        "lt" => Binary::Lt,
        "min" => Binary::Min,
        "max" => Binary::Max,
        "pow" => Binary::Pow,
        "atan2" => Binary::Atan2,
        "fmod" => Binary::Fmod,
        _ => return None,
    })
}

fn truth(b: bool) -> f64 {
    if b { 1.0 } else { 0.0 }
}

impl Expr {
    /// Evaluates with input values, output values and `x`. Unknown indices read NaN.
    pub fn eval(&self, inputs: &[f64], outputs: &[f64], x: f64) -> f64 {
        match self {
            Expr::Const(c) => *c,
            Expr::Var(VarRef::X) => x,
            Expr::Var(VarRef::Input(i)) => inputs.get(*i).copied().unwrap_or(f64::NAN),
            Expr::Var(VarRef::Output(i)) => outputs.get(*i).copied().unwrap_or(f64::NAN),
            Expr::Unary(f, a) => {
                let a = a.eval(inputs, outputs, x);
                match f {
                    Unary::Neg => -a,
                    Unary::Not => truth(!is_eq(a, 1.0)),
                    Unary::Acos => a.acos(),
                    Unary::Asin => a.asin(),
                    Unary::Atan => a.atan(),
                    Unary::Ceil => a.ceil(),
                    Unary::Cos => a.cos(),
                    Unary::Cosh => a.cosh(),
                    Unary::Exp => a.exp(),
                    Unary::Abs => a.abs(),
                    Unary::Floor => a.floor(),
                    Unary::Log => a.ln(),
                    Unary::Log10 => a.log10(),
                    Unary::Round => a.round(),
                    Unary::Sin => a.sin(),
                    Unary::Sinh => a.sinh(),
                    Unary::Sqrt => a.sqrt(),
                    Unary::Tan => a.tan(),
                    Unary::Tanh => a.tanh(),
                    Unary::Log1p => a.ln_1p(),
                    Unary::Acosh => a.acosh(),
                    Unary::Asinh => a.asinh(),
                    Unary::Atanh => a.atanh(),
                }
            }
            Expr::Binary(f, a, b) => {
                let a = a.eval(inputs, outputs, x);
                let b = b.eval(inputs, outputs, x);
                match f {
                    Binary::Add => a + b,
                    Binary::Sub => a - b,
                    Binary::Mul => a * b,
                    Binary::Div => a / b,
                    Binary::Mod | Binary::Fmod => a % b,
                    Binary::Pow => a.powf(b),
                    Binary::And => truth(is_eq(a, 1.0) && is_eq(b, 1.0)),
                    Binary::Or => truth(is_eq(a, 1.0) || is_eq(b, 1.0)),
                    Binary::Gt => truth(is_gt(a, b)),
                    Binary::Ge => truth(is_ge(a, b)),
                    Binary::Eq => truth(is_eq(a, b)),
                    Binary::Neq => truth(!is_eq(a, b)),
                    Binary::Le => truth(is_le(a, b)),
                    Binary::Lt => truth(is_lt(a, b)),
                    Binary::Min => min(a, b),
                    Binary::Max => max(a, b),
                    Binary::Atan2 => a.atan2(b),
                }
            }
        }
    }

    /// Every variable the expression reads.
    pub fn visit_vars(&self, f: &mut impl FnMut(VarRef)) {
        match self {
            Expr::Const(_) => {}
            Expr::Var(v) => f(*v),
            Expr::Unary(_, a) => a.visit_vars(f),
            Expr::Binary(_, a, b) => {
                a.visit_vars(f);
                b.visit_vars(f);
            }
        }
    }
}

#[derive(Debug, Clone, PartialEq)]
enum Tok {
    Num(f64),
    Ident(String),
    Op(char),
    LParen,
    RParen,
    Comma,
}

/// Parses a number as fuzzylite writes them: decimal or scientific, `nan`, `inf`, `-inf`.
pub fn parse_number(s: &str) -> Option<f64> {
    let t = s.trim();
    match t.to_ascii_lowercase().as_str() {
        "nan" | "+nan" | "-nan" => return Some(f64::NAN),
        "inf" | "+inf" | "infinity" | "+infinity" => return Some(f64::INFINITY),
        "-inf" | "-infinity" => return Some(f64::NEG_INFINITY),
        _ => {}
    }
    let first = t.chars().next()?;
    if !(first.is_ascii_digit() || matches!(first, '.' | '-' | '+')) {
        return None;
    }
    t.parse::<f64>().ok()
}

fn tokenize(text: &str) -> Result<Vec<Tok>, FuzzyError> {
    let chars: Vec<char> = text.chars().collect();
    let mut out = Vec::new();
    let mut i = 0;
    while i < chars.len() {
        let c = chars[i];
        if c.is_whitespace() {
            i += 1;
        } else if c.is_ascii_digit()
            || (c == '.' && chars.get(i + 1).is_some_and(|d| d.is_ascii_digit()))
        {
            let start = i;
            while i < chars.len() && (chars[i].is_ascii_digit() || chars[i] == '.') {
                i += 1;
            }
            if i < chars.len() && (chars[i] == 'e' || chars[i] == 'E') {
                let mut j = i + 1;
                if j < chars.len() && (chars[j] == '+' || chars[j] == '-') {
                    j += 1;
                }
                if j < chars.len() && chars[j].is_ascii_digit() {
                    i = j;
                    while i < chars.len() && chars[i].is_ascii_digit() {
                        i += 1;
                    }
                }
            }
            let s: String = chars[start..i].iter().collect();
            let v = s
                .parse::<f64>()
                .map_err(|_| FuzzyError::syntax(0, format!("malformed number '{s}'")))?;
            out.push(Tok::Num(v));
        } else if c.is_alphabetic() || c == '_' {
            let start = i;
            while i < chars.len()
                && (chars[i].is_alphanumeric() || chars[i] == '_' || chars[i] == '.')
            {
                i += 1;
            }
            out.push(Tok::Ident(chars[start..i].iter().collect()));
        } else {
            out.push(match c {
                '(' => Tok::LParen,
                ')' => Tok::RParen,
                ',' => Tok::Comma,
                '+' | '-' | '*' | '/' | '%' | '^' | '!' | '~' => Tok::Op(c),
                other => {
                    return Err(FuzzyError::syntax(
                        0,
                        format!("unexpected character '{other}' in formula"),
                    ));
                }
            });
            i += 1;
        }
    }
    Ok(out)
}

struct Parser<'a> {
    toks: Vec<Tok>,
    pos: usize,
    resolve: &'a dyn Fn(&str) -> Option<VarRef>,
    depth: usize,
}

impl Parser<'_> {
    fn peek(&self) -> Option<&Tok> {
        self.toks.get(self.pos)
    }

    fn err(&self, msg: impl Into<String>) -> FuzzyError {
        FuzzyError::syntax(0, msg)
    }

    fn enter(&mut self) -> Result<(), FuzzyError> {
        self.depth += 1;
        if self.depth > MAX_DEPTH {
            return Err(self.err(format!("formula nested deeper than {MAX_DEPTH} levels")));
        }
        Ok(())
    }

    fn binary_op(&self) -> Option<(Binary, u8)> {
        match self.peek()? {
            Tok::Ident(s) if s == "or" => Some((Binary::Or, 1)),
            Tok::Ident(s) if s == "and" => Some((Binary::And, 2)),
            Tok::Op('+') => Some((Binary::Add, 3)),
            Tok::Op('-') => Some((Binary::Sub, 3)),
            Tok::Op('*') => Some((Binary::Mul, 4)),
            Tok::Op('/') => Some((Binary::Div, 4)),
            Tok::Op('%') => Some((Binary::Mod, 4)),
            _ => None,
        }
    }

    fn expr(&mut self, min_prec: u8) -> Result<Expr, FuzzyError> {
        self.enter()?;
        let mut lhs = self.unary()?;
        while let Some((op, prec)) = self.binary_op() {
            if prec < min_prec {
                break;
            }
            self.pos += 1;
            let rhs = self.expr(prec + 1)?;
            lhs = Expr::Binary(op, Box::new(lhs), Box::new(rhs));
        }
        self.depth -= 1;
        Ok(lhs)
    }

    fn unary(&mut self) -> Result<Expr, FuzzyError> {
        let op = match self.peek() {
            Some(Tok::Op('-')) => Some(Unary::Neg),
            Some(Tok::Op('~')) => Some(Unary::Neg),
            Some(Tok::Op('!')) => Some(Unary::Not),
            Some(Tok::Op('+')) => {
                self.pos += 1;
                return self.unary();
            }
            _ => None,
        };
        if let Some(op) = op {
            self.pos += 1;
            self.enter()?;
            let a = self.unary()?;
            self.depth -= 1;
            return Ok(match (op, a) {
                (Unary::Neg, Expr::Const(c)) => Expr::Const(-c),
                (op, a) => Expr::Unary(op, Box::new(a)),
            });
        }
        let base = self.primary()?;
        if self.peek() == Some(&Tok::Op('^')) {
            self.pos += 1;
            self.enter()?;
            let exp = self.unary()?;
            self.depth -= 1;
            return Ok(Expr::Binary(Binary::Pow, Box::new(base), Box::new(exp)));
        }
        Ok(base)
    }

    fn expect(&mut self, t: Tok, what: &str) -> Result<(), FuzzyError> {
        if self.peek() == Some(&t) {
            self.pos += 1;
            Ok(())
        } else {
            Err(self.err(format!("expected {what}")))
        }
    }

    fn primary(&mut self) -> Result<Expr, FuzzyError> {
        match self.peek().cloned() {
            Some(Tok::Num(v)) => {
                self.pos += 1;
                Ok(Expr::Const(v))
            }
            Some(Tok::LParen) => {
                self.pos += 1;
                let e = self.expr(0)?;
                self.expect(Tok::RParen, "')'")?;
                Ok(e)
            }
            Some(Tok::Ident(name)) => {
                self.pos += 1;
                if self.peek() == Some(&Tok::LParen) {
                    self.pos += 1;
                    self.enter()?;
                    let out = if let Some(f) = unary_by_name(&name) {
                        let a = self.expr(0)?;
                        Expr::Unary(f, Box::new(a))
                    } else if let Some(f) = binary_fn_by_name(&name) {
                        let a = self.expr(0)?;
                        self.expect(
                            Tok::Comma,
                            &format!("',' between the two arguments of {name}"),
                        )?;
                        let b = self.expr(0)?;
                        Expr::Binary(f, Box::new(a), Box::new(b))
                    } else {
                        return Err(self.err(format!("unknown function '{name}'")));
                    };
                    self.depth -= 1;
                    self.expect(Tok::RParen, &format!("')' closing {name}("))?;
                    return Ok(out);
                }
                if let Some(v) = parse_number(&name) {
                    return Ok(Expr::Const(v));
                }
                if name == "x" {
                    if let Some(v) = (self.resolve)("x") {
                        return Ok(Expr::Var(v));
                    }
                    return Ok(Expr::Var(VarRef::X));
                }
                (self.resolve)(&name)
                    .map(Expr::Var)
                    .ok_or_else(|| self.err(format!("unknown variable '{name}' in formula")))
            }
            Some(t) => Err(self.err(format!("unexpected {t:?} in formula"))),
            None => Err(self.err("formula ends too early")),
        }
    }
}

/// Parses `text`, resolving variable names with `resolve` (`x` is the membership argument unless a variable is
/// called `x`).
pub fn parse(text: &str, resolve: &dyn Fn(&str) -> Option<VarRef>) -> Result<Expr, FuzzyError> {
    let toks = tokenize(text)?;
    if toks.is_empty() {
        return Err(FuzzyError::syntax(0, "empty formula"));
    }
    let mut p = Parser {
        toks,
        pos: 0,
        resolve,
        depth: 0,
    };
    let e = p.expr(0)?;
    if p.pos != p.toks.len() {
        return Err(FuzzyError::syntax(
            0,
            format!(
                "unexpected {:?} after the end of the formula",
                p.toks[p.pos]
            ),
        ));
    }
    Ok(e)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn eval(s: &str) -> f64 {
        let resolve = |n: &str| {
            if n == "a" {
                Some(VarRef::Input(0))
            } else {
                None
            }
        };
        parse(s, &resolve).expect("parses").eval(&[2.0], &[], 0.5)
    }

    #[test]
    fn precedence_and_functions() {
        assert_eq!(eval("1 + 2 * 3"), 7.0);
        assert_eq!(eval("(1 + 2) * 3"), 9.0);
        assert_eq!(eval("2 ^ 3 ^ 2"), 512.0);
        assert_eq!(eval("-a ^ 2"), -4.0);
        assert_eq!(eval("10 - 4 - 3"), 3.0);
        assert_eq!(eval("pow(a, 3) + max(1, x)"), 9.0);
        assert!((eval("sin(a)/a") - 2f64.sin() / 2.0).abs() < 1e-15);
        assert_eq!(eval("fabs(x - a)"), 1.5);
        assert_eq!(eval("1 and 0 or 1"), 1.0);
        assert_eq!(eval("gt(a, 1)"), 1.0);
        assert_eq!(eval("1.5e1"), 15.0);
    }

    #[test]
    fn bad_formulas_are_refused() {
        let resolve = |_: &str| None;
        for bad in [
            "", "1 +", "(1", "foo(1)", "b + 1", "pow(1)", "1 2", "sin 1", "#", "1..2",
        ] {
            assert!(parse(bad, &resolve).is_err(), "{bad}");
        }
        let deep = format!("{}1{}", "(".repeat(1000), ")".repeat(1000));
        assert!(parse(&deep, &resolve).is_err());
        let deep = format!("{}1", "-".repeat(1000));
        assert!(parse(&deep, &resolve).is_err());
    }
}
