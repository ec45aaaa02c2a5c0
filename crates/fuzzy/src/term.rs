//! Linguistic terms: membership functions with fuzzylite's exact definitions (including its tolerant
//! comparisons at the breakpoints), their inverse for Tsukamoto inference, and their FLL parameters.

use crate::error::FuzzyError;
use crate::expr::{self, Expr, VarRef, parse_number};
use crate::ops::{is_eq, is_ge, is_gt, is_le, is_lt, min};

/// A membership function. `h` is the height (1 unless given).
#[derive(Debug, Clone, PartialEq)]
#[allow(missing_docs)]
pub enum Shape {
    Triangle {
        a: f64,
        b: f64,
        c: f64,
        h: f64,
    },
    Trapezoid {
        a: f64,
        b: f64,
        c: f64,
        d: f64,
        h: f64,
    },
    Rectangle {
        start: f64,
        end: f64,
        h: f64,
    },
    Gaussian {
        mean: f64,
        sd: f64,
        h: f64,
    },
    GaussianProduct {
        mean_a: f64,
        sd_a: f64,
        mean_b: f64,
        sd_b: f64,
        h: f64,
    },
    Bell {
        center: f64,
        width: f64,
        slope: f64,
        h: f64,
    },
    Sigmoid {
        inflection: f64,
        slope: f64,
        h: f64,
    },
    SigmoidDifference {
        left: f64,
        rising: f64,
        falling: f64,
        right: f64,
        h: f64,
    },
    SigmoidProduct {
        left: f64,
        rising: f64,
        falling: f64,
        right: f64,
        h: f64,
    },
    SShape {
        start: f64,
        end: f64,
        h: f64,
    },
    ZShape {
        start: f64,
        end: f64,
        h: f64,
    },
    PiShape {
        bottom_left: f64,
        top_left: f64,
        top_right: f64,
        bottom_right: f64,
        h: f64,
    },
    Ramp {
        start: f64,
        end: f64,
        h: f64,
    },
    Cosine {
        center: f64,
        width: f64,
        h: f64,
    },
    Concave {
        inflection: f64,
        end: f64,
        h: f64,
    },
    Spike {
        center: f64,
        width: f64,
        h: f64,
    },
    Binary {
        start: f64,
        direction: f64,
        h: f64,
    },
    Discrete {
        xy: Vec<(f64, f64)>,
        h: f64,
    },
    /// A constant output (Takagi-Sugeno).
    Constant {
        value: f64,
    },
    /// `c0 in0 + c1 in1 + ... (+ constant)` over the input variables (Takagi-Sugeno).
    Linear {
        coefficients: Vec<f64>,
    },
    /// An arithmetic formula of `x` and the engine's variables; compiled when the engine is built.
    Function {
        formula: String,
        compiled: Option<Expr>,
    },
}

/// A named term of a variable.
#[derive(Debug, Clone, PartialEq)]
pub struct Term {
    /// The name used in rules.
    pub name: String,
    /// The membership function.
    pub shape: Shape,
}

/// Class names accepted in FLL and FCL.
pub const CLASSES: [&str; 21] = [
    "Triangle",
    "Trapezoid",
    "Rectangle",
    "Gaussian",
    "GaussianProduct",
    "Bell",
    "Sigmoid",
    "SigmoidDifference",
    "SigmoidProduct",
    "SShape",
    "ZShape",
    "PiShape",
    "Ramp",
    "Cosine",
    "Concave",
    "Spike",
    "Binary",
    "Discrete",
    "Constant",
    "Linear",
    "Function",
];

fn sigmoid(x: f64, inflection: f64, slope: f64) -> f64 {
    1.0 / (1.0 + (-slope * (x - inflection)).exp())
}

impl Shape {
    /// Membership of `x`; `inputs` and `outputs` are the engine's current values (for Linear and Function).
    pub fn membership(&self, x: f64, inputs: &[f64], outputs: &[f64]) -> f64 {
        use Shape::*;
        // Constant, Linear and Function do not look at NaN specially.
        match self {
            Constant { value } => return *value,
            Linear { coefficients } => {
                let mut r = 0.0;
                for (c, v) in coefficients.iter().zip(inputs) {
                    r += c * v;
                }
                if coefficients.len() > inputs.len() {
                    if let Some(last) = coefficients.last() {
                        r += last;
                    }
                }
                return r;
            }
            Function { compiled, .. } => {
                return compiled
                    .as_ref()
                    .map_or(f64::NAN, |e| e.eval(inputs, outputs, x));
            }
            _ => {}
        }
        if x.is_nan() {
            return f64::NAN;
        }
        match *self {
            Triangle { a, b, c, h } => {
                if is_lt(x, a) || is_gt(x, c) {
                    h * 0.0
                } else if is_eq(x, b) {
                    h
                } else if is_lt(x, b) {
                    if a == f64::NEG_INFINITY {
                        h
                    } else {
                        h * (x - a) / (b - a)
                    }
                } else if c == f64::INFINITY {
                    h
                } else {
                    h * (c - x) / (c - b)
                }
            }
            Trapezoid { a, b, c, d, h } => {
                if is_lt(x, a) || is_gt(x, d) {
                    h * 0.0
                } else if is_lt(x, b) {
                    if a == f64::NEG_INFINITY {
                        h
                    } else {
                        h * min(1.0, (x - a) / (b - a))
                    }
                } else if is_le(x, c) {
                    h
                } else if is_lt(x, d) {
                    if d == f64::INFINITY {
                        h
                    } else {
                        h * (d - x) / (d - c)
                    }
                } else if d == f64::INFINITY {
                    h
                } else {
                    h * 0.0
                }
            }
            Rectangle { start, end, h } => {
                if is_ge(x, start) && is_le(x, end) {
                    h
                } else {
                    h * 0.0
                }
            }
            Gaussian { mean, sd, h } => h * (-(x - mean) * (x - mean) / (2.0 * sd * sd)).exp(),
            GaussianProduct {
                mean_a,
                sd_a,
                mean_b,
                sd_b,
                h,
            } => {
                let a = if is_lt(x, mean_a) {
                    (-(x - mean_a) * (x - mean_a) / (2.0 * sd_a * sd_a)).exp()
                } else {
                    1.0
                };
                let b = if is_gt(x, mean_b) {
                    (-(x - mean_b) * (x - mean_b) / (2.0 * sd_b * sd_b)).exp()
                } else {
                    1.0
                };
                h * a * b
            }
            Bell {
                center,
                width,
                slope,
                h,
            } => h * (1.0 / (1.0 + ((x - center) / width).abs().powf(2.0 * slope))),
            Sigmoid {
                inflection,
                slope,
                h,
            } => h * sigmoid(x, inflection, slope),
            SigmoidDifference {
                left,
                rising,
                falling,
                right,
                h,
            } => h * (sigmoid(x, left, rising) - sigmoid(x, right, falling)).abs(),
            SigmoidProduct {
                left,
                rising,
                falling,
                right,
                h,
            } => h * sigmoid(x, left, rising) * sigmoid(x, right, falling),
            SShape { start, end, h } => {
                if is_le(x, start) {
                    h * 0.0
                } else if is_le(x, 0.5 * (start + end)) {
                    h * (2.0 * ((x - start) / (end - start)).powi(2))
                } else if is_lt(x, end) {
                    h * (1.0 - 2.0 * ((x - end) / (end - start)).powi(2))
                } else {
                    h
                }
            }
            ZShape { start, end, h } => {
                if is_le(x, start) {
                    h
                } else if is_le(x, 0.5 * (start + end)) {
                    h * (1.0 - 2.0 * ((x - start) / (end - start)).powi(2))
                } else if is_lt(x, end) {
                    h * (2.0 * ((x - end) / (end - start)).powi(2))
                } else {
                    h * 0.0
                }
            }
            PiShape {
                bottom_left: bl,
                top_left: tl,
                top_right: tr,
                bottom_right: br,
                h,
            } => {
                let s = if is_le(x, bl) {
                    0.0
                } else if is_le(x, 0.5 * (bl + tl)) {
                    2.0 * ((x - bl) / (tl - bl)).powi(2)
                } else if is_lt(x, tl) {
                    1.0 - 2.0 * ((x - tl) / (tl - bl)).powi(2)
                } else {
                    1.0
                };
                let z = if is_le(x, tr) {
                    1.0
                } else if is_le(x, 0.5 * (tr + br)) {
                    1.0 - 2.0 * ((x - tr) / (br - tr)).powi(2)
                } else if is_lt(x, br) {
                    2.0 * ((x - br) / (br - tr)).powi(2)
                } else {
                    0.0
                };
                h * s * z
            }
            Ramp { start, end, h } => {
                if is_eq(start, end) {
                    f64::NAN
                } else if is_lt(start, end) {
                    if is_le(x, start) {
                        h * 0.0
                    } else if is_ge(x, end) {
                        h
                    } else {
                        h * (x - start) / (end - start)
                    }
                } else if is_ge(x, start) {
                    h * 0.0
                } else if is_le(x, end) {
                    h
                } else {
                    h * (start - x) / (start - end)
                }
            }
            Cosine { center, width, h } => {
                if is_lt(x, center - 0.5 * width) || is_gt(x, center + 0.5 * width) {
                    h * 0.0
                } else {
                    h * (0.5 * (1.0 + (2.0 / width * std::f64::consts::PI * (x - center)).cos()))
                }
            }
            Concave {
                inflection: i,
                end: e,
                h,
            } => {
                if is_le(i, e) {
                    if is_lt(x, e) {
                        return h * (e - i) / (2.0 * e - i - x);
                    }
                } else if is_gt(x, e) {
                    return h * (i - e) / (i - 2.0 * e + x);
                }
                h
            }
            Spike { center, width, h } => h * (-(10.0 / width * (x - center)).abs()).exp(),
            Binary {
                start,
                direction,
                h,
            } => {
                if (direction > start && is_ge(x, start)) || (direction < start && is_le(x, start))
                {
                    h
                } else {
                    h * 0.0
                }
            }
            Discrete { ref xy, h } => discrete(xy, x) * h,
            Constant { .. } | Linear { .. } | Function { .. } => f64::NAN,
        }
    }

    /// The x at which a monotonic term reaches `y` (Tsukamoto inference), or `None` for other terms.
    pub fn tsukamoto(&self, y: f64) -> Option<f64> {
        Some(match *self {
            Shape::Ramp {
                start: s,
                end: e,
                h,
            } => s + (e - s) * y / h,
            Shape::Sigmoid {
                inflection: i,
                slope: s,
                h,
            } => i + (h / y - 1.0).ln() / -s,
            Shape::SShape {
                start: s,
                end: e,
                h,
            } => {
                if y <= h / 2.0 {
                    s + (e - s) * (y / (2.0 * h)).sqrt()
                } else {
                    e - (e - s) * ((h - y) / (2.0 * h)).sqrt()
                }
            }
            Shape::ZShape {
                start: s,
                end: e,
                h,
            } => {
                if y <= h / 2.0 {
                    e - (e - s) * (y / (2.0 * h)).sqrt()
                } else {
                    s + (e - s) * ((h - y) / (2.0 * h)).sqrt()
                }
            }
            Shape::Concave {
                inflection: i,
                end: e,
                h,
            } => h * (i - e) / y + 2.0 * e - i,
            _ => return None,
        })
    }

    /// True for Constant, Linear and Function (the consequents of Takagi-Sugeno rules).
    pub fn is_takagi_sugeno(&self) -> bool {
        matches!(
            self,
            Shape::Constant { .. } | Shape::Linear { .. } | Shape::Function { .. }
        )
    }

    /// True for the terms [`Shape::tsukamoto`] can invert.
    pub fn is_monotonic(&self) -> bool {
        matches!(
            self,
            Shape::Ramp { .. }
                | Shape::Sigmoid { .. }
                | Shape::SShape { .. }
                | Shape::ZShape { .. }
                | Shape::Concave { .. }
        )
    }

    /// The FLL class name.
    pub fn class(&self) -> &'static str {
        match self {
            Shape::Triangle { .. } => "Triangle",
            Shape::Trapezoid { .. } => "Trapezoid",
            Shape::Rectangle { .. } => "Rectangle",
            Shape::Gaussian { .. } => "Gaussian",
            Shape::GaussianProduct { .. } => "GaussianProduct",
            Shape::Bell { .. } => "Bell",
            Shape::Sigmoid { .. } => "Sigmoid",
            Shape::SigmoidDifference { .. } => "SigmoidDifference",
            Shape::SigmoidProduct { .. } => "SigmoidProduct",
            Shape::SShape { .. } => "SShape",
            Shape::ZShape { .. } => "ZShape",
            Shape::PiShape { .. } => "PiShape",
            Shape::Ramp { .. } => "Ramp",
            Shape::Cosine { .. } => "Cosine",
            Shape::Concave { .. } => "Concave",
            Shape::Spike { .. } => "Spike",
            Shape::Binary { .. } => "Binary",
            Shape::Discrete { .. } => "Discrete",
            Shape::Constant { .. } => "Constant",
            Shape::Linear { .. } => "Linear",
            Shape::Function { .. } => "Function",
        }
    }

    /// The parameters as written after the class name in FLL (numbers in shortest exact form).
    pub fn parameters(&self) -> String {
        use Shape::*;
        let nums = |v: &[f64], h: f64| {
            let mut s: Vec<String> = v.iter().map(|x| fmt_num(*x)).collect();
            if h != 1.0 {
                s.push(fmt_num(h));
            }
            s.join(" ")
        };
        match self {
            Triangle { a, b, c, h } => nums(&[*a, *b, *c], *h),
            Trapezoid { a, b, c, d, h } => nums(&[*a, *b, *c, *d], *h),
            Rectangle { start, end, h } => nums(&[*start, *end], *h),
            Gaussian { mean, sd, h } => nums(&[*mean, *sd], *h),
            GaussianProduct {
                mean_a,
                sd_a,
                mean_b,
                sd_b,
                h,
            } => nums(&[*mean_a, *sd_a, *mean_b, *sd_b], *h),
            Bell {
                center,
                width,
                slope,
                h,
            } => nums(&[*center, *width, *slope], *h),
            Sigmoid {
                inflection,
                slope,
                h,
            } => nums(&[*inflection, *slope], *h),
            SigmoidDifference {
                left,
                rising,
                falling,
                right,
                h,
            }
            | SigmoidProduct {
                left,
                rising,
                falling,
                right,
                h,
            } => nums(&[*left, *rising, *falling, *right], *h),
            SShape { start, end, h } | ZShape { start, end, h } | Ramp { start, end, h } => {
                nums(&[*start, *end], *h)
            }
            PiShape {
                bottom_left,
                top_left,
                top_right,
                bottom_right,
                h,
            } => nums(&[*bottom_left, *top_left, *top_right, *bottom_right], *h),
            Cosine { center, width, h } | Spike { center, width, h } => {
                nums(&[*center, *width], *h)
            }
            Concave { inflection, end, h } => nums(&[*inflection, *end], *h),
            Binary {
                start,
                direction,
                h,
            } => nums(&[*start, *direction], *h),
            Discrete { xy, h } => nums(
                &xy.iter().flat_map(|&(x, y)| [x, y]).collect::<Vec<_>>(),
                *h,
            ),
            Constant { value } => fmt_num(*value),
            Linear { coefficients } => nums(coefficients, 1.0),
            Function { formula, .. } => formula.clone(),
        }
    }

    /// Builds a term of `class` from its parameters (a formula for `Function`). The error names what is wrong.
    pub fn configure(class: &str, params: &str) -> Result<Shape, FuzzyError> {
        use Shape::*;
        if class == "Function" {
            if params.trim().is_empty() {
                return Err(FuzzyError::syntax(0, "term Function needs a formula"));
            }
            return Ok(Function {
                formula: params.trim().to_string(),
                compiled: None,
            });
        }
        let mut v = Vec::new();
        for tok in params.split_whitespace() {
            v.push(parse_number(tok).ok_or_else(|| {
                FuzzyError::syntax(
                    0,
                    format!("term {class}: parameter '{tok}' is not a number"),
                )
            })?);
        }
        let fixed = |n: usize| -> Result<(Vec<f64>, f64), FuzzyError> {
            if v.len() == n {
                Ok((v.clone(), 1.0))
            } else if v.len() == n + 1 {
                Ok((v[..n].to_vec(), v[n]))
            } else {
                Err(FuzzyError::syntax(
                    0,
                    format!(
                        "term {class} takes {n} parameters (and optionally a height), but {} were given",
                        v.len()
                    ),
                ))
            }
        };
        Ok(match class {
            "Triangle" => {
                let (p, h) = fixed(3)?;
                Triangle {
                    a: p[0],
                    b: p[1],
                    c: p[2],
                    h,
                }
            }
            "Trapezoid" => {
                let (p, h) = fixed(4)?;
                Trapezoid {
                    a: p[0],
                    b: p[1],
                    c: p[2],
                    d: p[3],
                    h,
                }
            }
            "Rectangle" => {
                let (p, h) = fixed(2)?;
                Rectangle {
                    start: p[0],
                    end: p[1],
                    h,
                }
            }
            "Gaussian" => {
                let (p, h) = fixed(2)?;
                Gaussian {
                    mean: p[0],
                    sd: p[1],
                    h,
                }
            }
            "GaussianProduct" => {
                let (p, h) = fixed(4)?;
                GaussianProduct {
                    mean_a: p[0],
                    sd_a: p[1],
                    mean_b: p[2],
                    sd_b: p[3],
                    h,
                }
            }
            "Bell" => {
                let (p, h) = fixed(3)?;
                Bell {
                    center: p[0],
                    width: p[1],
                    slope: p[2],
                    h,
                }
            }
            "Sigmoid" => {
                let (p, h) = fixed(2)?;
                Sigmoid {
                    inflection: p[0],
                    slope: p[1],
                    h,
                }
            }
            "SigmoidDifference" => {
                let (p, h) = fixed(4)?;
                SigmoidDifference {
                    left: p[0],
                    rising: p[1],
                    falling: p[2],
                    right: p[3],
                    h,
                }
            }
            "SigmoidProduct" => {
                let (p, h) = fixed(4)?;
                SigmoidProduct {
                    left: p[0],
                    rising: p[1],
                    falling: p[2],
                    right: p[3],
                    h,
                }
            }
            "SShape" => {
                let (p, h) = fixed(2)?;
                SShape {
                    start: p[0],
                    end: p[1],
                    h,
                }
            }
            "ZShape" => {
                let (p, h) = fixed(2)?;
                ZShape {
                    start: p[0],
                    end: p[1],
                    h,
                }
            }
            "PiShape" => {
                let (p, h) = fixed(4)?;
                PiShape {
                    bottom_left: p[0],
                    top_left: p[1],
                    top_right: p[2],
                    bottom_right: p[3],
                    h,
                }
            }
            "Ramp" => {
                let (p, h) = fixed(2)?;
                Ramp {
                    start: p[0],
                    end: p[1],
                    h,
                }
            }
            "Cosine" => {
                let (p, h) = fixed(2)?;
                Cosine {
                    center: p[0],
                    width: p[1],
                    h,
                }
            }
            "Concave" => {
                let (p, h) = fixed(2)?;
                Concave {
                    inflection: p[0],
                    end: p[1],
                    h,
                }
            }
            "Spike" => {
                let (p, h) = fixed(2)?;
                Spike {
                    center: p[0],
                    width: p[1],
                    h,
                }
            }
            "Binary" => {
                let (p, h) = fixed(2)?;
                Binary {
                    start: p[0],
                    direction: p[1],
                    h,
                }
            }
            "Discrete" => {
                if v.len() < 2 {
                    return Err(FuzzyError::syntax(
                        0,
                        "term Discrete needs at least one x y pair",
                    ));
                }
                let h = if v.len() % 2 == 1 {
                    v.pop().unwrap_or(1.0)
                } else {
                    1.0
                };
                let xy: Vec<(f64, f64)> = v.chunks(2).map(|c| (c[0], c[1])).collect();
                if xy.windows(2).any(|w| {
                    w[0].0.partial_cmp(&w[1].0) != Some(std::cmp::Ordering::Less)
                        && w[0].0 != w[1].0
                }) {
                    return Err(FuzzyError::syntax(
                        0,
                        "term Discrete: the x values must be in ascending order",
                    ));
                }
                Discrete { xy, h }
            }
            "Constant" => {
                if v.len() != 1 {
                    return Err(FuzzyError::syntax(
                        0,
                        format!(
                            "term Constant takes 1 parameter, but {} were given",
                            v.len()
                        ),
                    ));
                }
                Constant { value: v[0] }
            }
            "Linear" => Linear { coefficients: v },
            other => {
                return Err(FuzzyError::syntax(
                    0,
                    format!(
                        "unknown term class '{other}' (known: {})",
                        CLASSES.join(", ")
                    ),
                ));
            }
        })
    }

    /// Compiles a Function term's formula with `resolve` mapping names to variables.
    pub fn compile(&mut self, resolve: &dyn Fn(&str) -> Option<VarRef>) -> Result<(), FuzzyError> {
        if let Shape::Function { formula, compiled } = self {
            *compiled = Some(expr::parse(formula, resolve)?);
        }
        Ok(())
    }
}

/// Piecewise-linear membership of a Discrete term (height 1), as fuzzylite interpolates it.
fn discrete(xy: &[(f64, f64)], x: f64) -> f64 {
    let (Some(first), Some(last)) = (xy.first(), xy.last()) else {
        return f64::NAN;
    };
    if is_le(x, first.0) {
        return first.1;
    }
    if is_ge(x, last.0) {
        return last.1;
    }
    let lower = xy.partition_point(|p| p.0 < x);
    if let Some(p) = xy.get(lower) {
        if is_eq(x, p.0) {
            return p.1;
        }
    }
    let upper = xy.partition_point(|p| p.0 <= x);
    let (Some(lo), Some(hi)) = (lower.checked_sub(1).and_then(|i| xy.get(i)), xy.get(upper)) else {
        return f64::NAN;
    };
    (hi.1 - lo.1) / (hi.0 - lo.0) * (x - lo.0) + lo.1
}

/// Formats a number so that reading it back gives the same `f64`: `nan`, `inf`, `-inf` or Rust's shortest form.
pub fn fmt_num(x: f64) -> String {
    if x.is_nan() {
        "nan".into()
    } else if x == f64::INFINITY {
        "inf".into()
    } else if x == f64::NEG_INFINITY {
        "-inf".into()
    } else {
        format!("{x}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn m(class: &str, p: &str, x: f64) -> f64 {
        Shape::configure(class, p)
            .expect("term")
            .membership(x, &[], &[])
    }

    #[test]
    fn shapes_take_their_defining_values() {
        assert_eq!(m("Triangle", "0 1 2", 1.0), 1.0);
        assert_eq!(m("Triangle", "0 1 2", 0.5), 0.5);
        assert_eq!(m("Triangle", "0 1 2 0.5", 1.5), 0.25);
        assert_eq!(m("Trapezoid", "0 1 2 3", 2.5), 0.5);
        assert_eq!(m("Rectangle", "1 2", 1.0), 1.0);
        assert_eq!(m("Gaussian", "0 1", 0.0), 1.0);
        assert_eq!(m("Bell", "0 1 2", 1.0), 0.5);
        assert_eq!(m("Sigmoid", "0 5", 0.0), 0.5);
        assert_eq!(m("SShape", "0 2", 1.0), 0.5);
        assert_eq!(m("ZShape", "0 2", 1.0), 0.5);
        assert_eq!(m("Ramp", "0 2", 1.5), 0.75);
        assert_eq!(m("Ramp", "2 0", 1.5), 0.25);
        assert!(m("Ramp", "1 1", 0.5).is_nan());
        assert_eq!(m("Cosine", "0 2", 0.0), 1.0);
        assert_eq!(m("Concave", "1 2", 0.0), 1.0 / 3.0);
        assert_eq!(m("Spike", "0 10", 0.0), 1.0);
        assert_eq!(m("Binary", "1 inf", 2.0), 1.0);
        assert_eq!(m("Binary", "1 inf", 0.0), 0.0);
        assert_eq!(m("Discrete", "0 0 1 1 2 0", 0.5), 0.5);
        assert_eq!(m("Discrete", "0 0 1 1 2 0", 1.5), 0.5);
        assert_eq!(m("Constant", "3.5", 0.0), 3.5);
        assert!(m("Triangle", "0 1 2", f64::NAN).is_nan());
        assert_eq!(m("PiShape", "0 1 2 3", 1.5), 1.0);
    }

    #[test]
    fn tsukamoto_inverts_monotonic_terms() {
        for (class, p) in [
            ("Ramp", "0 2"),
            ("Sigmoid", "1 3"),
            ("SShape", "0 2"),
            ("ZShape", "0 2"),
            ("Concave", "1 2"),
        ] {
            let s = Shape::configure(class, p).expect("term");
            for y in [0.1, 0.3, 0.6, 0.9] {
                let x = s.tsukamoto(y).expect("monotonic");
                assert!(
                    (s.membership(x, &[], &[]) - y).abs() < 1e-9,
                    "{class} y={y} x={x}"
                );
            }
        }
        assert!(
            Shape::configure("Triangle", "0 1 2")
                .expect("t")
                .tsukamoto(0.5)
                .is_none()
        );
    }

    #[test]
    fn bad_parameters_are_refused() {
        assert!(Shape::configure("Triangle", "0 1").is_err());
        assert!(Shape::configure("Triangle", "0 1 2 3 4").is_err());
        assert!(Shape::configure("Triangle", "0 one 2").is_err());
        assert!(Shape::configure("Blob", "0").is_err());
        assert!(Shape::configure("Discrete", "1 0 0 1").is_err());
        assert!(Shape::configure("Constant", "").is_err());
        assert!(Shape::configure("Function", " ").is_err());
    }

    #[test]
    fn parameters_round_trip() {
        for (class, p) in [
            ("Triangle", "0.1 0.25 1e-7 0.5"),
            ("Discrete", "0 0 1 1 2 0"),
            ("Binary", "0 -inf"),
            ("Linear", "1 -2.5 3"),
        ] {
            let s = Shape::configure(class, p).expect("term");
            assert_eq!(Shape::configure(class, &s.parameters()).expect("again"), s);
        }
    }
}
