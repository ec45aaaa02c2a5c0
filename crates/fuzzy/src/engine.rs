//! The inference engine: variables, rule blocks, activation, aggregation, defuzzification.
//!
//! Semantics follow fuzzylite 7 (the reference the conformance test compares with): rules are activated block by
//! block in order; a rule fires when its activation degree (weight × antecedent) is greater than zero within
//! [`crate::ops::MACHEPS`]; an output proposition in an antecedent reads the degree its term has been activated
//! with so far (chained engines); outputs are defuzzified in order, and an output without activated terms, or
//! whose defuzzification fails, takes its previous value (with lock-previous) or its default.
//!
//! After [`Engine::load`], evaluation allocates nothing: every buffer is sized when the engine is built.

use crate::error::FuzzyError;
use crate::expr::VarRef;
use crate::ops::{Hedge, SNorm, TNorm, bound, is_eq, is_ge, is_gt, is_le, is_lt};
use crate::term::{Shape, Term};

/// Largest resolution of an integral defuzzifier.
pub const MAX_RESOLUTION: usize = 1_000_000;
/// Resolution of integral defuzzifiers when a file gives none (fuzzylite's default).
pub const DEFAULT_RESOLUTION: usize = 1000;

/// An input variable.
#[derive(Debug, Clone, PartialEq)]
pub struct InputVariable {
    /// Name used in rules.
    pub name: String,
    /// Free text.
    pub description: String,
    /// Disabled variables make their propositions 0.
    pub enabled: bool,
    /// Lower end of the range.
    pub minimum: f64,
    /// Upper end of the range.
    pub maximum: f64,
    /// Clamp values set into the range.
    pub lock_range: bool,
    /// Terms.
    pub terms: Vec<Term>,
}

impl InputVariable {
    /// An enabled input variable without terms over an unbounded range (fuzzylite's defaults).
    pub fn new(name: impl Into<String>) -> Self {
        Self {
            name: name.into(),
            description: String::new(),
            enabled: true,
            minimum: f64::NEG_INFINITY,
            maximum: f64::INFINITY,
            lock_range: false,
            terms: vec![],
        }
    }
}

/// How a weighted defuzzifier computes each rule's crisp output.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WeightedType {
    /// Inferred from the terms: Takagi-Sugeno for Constant/Linear/Function, Tsukamoto for monotonic terms.
    Automatic,
    /// z = term value at the activation degree (Constant, Linear, Function).
    TakagiSugeno,
    /// z = the x at which a monotonic term reaches the activation degree.
    Tsukamoto,
}

impl WeightedType {
    /// The FLL keyword.
    pub fn name(self) -> &'static str {
        match self {
            WeightedType::Automatic => "Automatic",
            WeightedType::TakagiSugeno => "TakagiSugeno",
            WeightedType::Tsukamoto => "Tsukamoto",
        }
    }
}

/// Defuzzifiers: integral ones (over the aggregated fuzzy set, sampled at `resolution` midpoints) and weighted ones.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Defuzzifier {
    /// Centre of gravity.
    Centroid(usize),
    /// x splitting the area in two halves.
    Bisector(usize),
    /// Smallest x of maximum membership.
    SmallestOfMaximum(usize),
    /// Largest x of maximum membership.
    LargestOfMaximum(usize),
    /// Mean of the x of maximum membership.
    MeanOfMaximum(usize),
    /// Σ w z / Σ w.
    WeightedAverage(WeightedType),
    /// Σ w z.
    WeightedSum(WeightedType),
}

impl Defuzzifier {
    /// The FLL class name.
    pub fn name(&self) -> &'static str {
        match self {
            Defuzzifier::Centroid(_) => "Centroid",
            Defuzzifier::Bisector(_) => "Bisector",
            Defuzzifier::SmallestOfMaximum(_) => "SmallestOfMaximum",
            Defuzzifier::LargestOfMaximum(_) => "LargestOfMaximum",
            Defuzzifier::MeanOfMaximum(_) => "MeanOfMaximum",
            Defuzzifier::WeightedAverage(_) => "WeightedAverage",
            Defuzzifier::WeightedSum(_) => "WeightedSum",
        }
    }

    /// True for the integral (sampling) defuzzifiers.
    pub fn is_integral(&self) -> bool {
        !matches!(
            self,
            Defuzzifier::WeightedAverage(_) | Defuzzifier::WeightedSum(_)
        )
    }

    /// Builds a defuzzifier from its FLL name and optional parameter.
    pub fn from_name(name: &str, param: Option<&str>) -> Result<Defuzzifier, FuzzyError> {
        let resolution = || -> Result<usize, FuzzyError> {
            match param {
                None => Ok(DEFAULT_RESOLUTION),
                Some(p) => {
                    let v = crate::expr::parse_number(p)
                        .filter(|v| v.fract() == 0.0 && *v >= 1.0 && *v <= MAX_RESOLUTION as f64)
                        .ok_or_else(|| {
                            FuzzyError::syntax(0, format!("resolution '{p}' must be a whole number from 1 to {MAX_RESOLUTION}"))
                        })?;
                    Ok(v as usize)
                }
            }
        };
        let weighted = || -> Result<WeightedType, FuzzyError> {
            match param {
                None | Some("Automatic") => Ok(WeightedType::Automatic),
                Some("TakagiSugeno") => Ok(WeightedType::TakagiSugeno),
                Some("Tsukamoto") => Ok(WeightedType::Tsukamoto),
                Some(other) => Err(FuzzyError::syntax(
                    0,
                    format!(
                        "unknown type '{other}' of {name}: use Automatic, TakagiSugeno or Tsukamoto"
                    ),
                )),
            }
        };
        Ok(match name {
            "Centroid" => Defuzzifier::Centroid(resolution()?),
            "Bisector" => Defuzzifier::Bisector(resolution()?),
            "SmallestOfMaximum" => Defuzzifier::SmallestOfMaximum(resolution()?),
            "LargestOfMaximum" => Defuzzifier::LargestOfMaximum(resolution()?),
            "MeanOfMaximum" => Defuzzifier::MeanOfMaximum(resolution()?),
            "WeightedAverage" => Defuzzifier::WeightedAverage(weighted()?),
            "WeightedSum" => Defuzzifier::WeightedSum(weighted()?),
            other => {
                return Err(FuzzyError::syntax(
                    0,
                    format!("unknown defuzzifier '{other}'"),
                ));
            }
        })
    }

    /// The parameter written after the name in FLL.
    pub fn parameter(&self) -> String {
        match self {
            Defuzzifier::Centroid(r)
            | Defuzzifier::Bisector(r)
            | Defuzzifier::SmallestOfMaximum(r)
            | Defuzzifier::LargestOfMaximum(r)
            | Defuzzifier::MeanOfMaximum(r) => r.to_string(),
            Defuzzifier::WeightedAverage(t) | Defuzzifier::WeightedSum(t) => t.name().to_string(),
        }
    }
}

/// An output variable.
#[derive(Debug, Clone)]
pub struct OutputVariable {
    /// Name used in rules.
    pub name: String,
    /// Free text.
    pub description: String,
    /// Disabled outputs are not defuzzified and receive no conclusions.
    pub enabled: bool,
    /// Lower end of the range (the defuzzification interval).
    pub minimum: f64,
    /// Upper end of the range.
    pub maximum: f64,
    /// Clamp the defuzzified value into the range.
    pub lock_range: bool,
    /// Aggregation of the activated terms.
    pub aggregation: Option<SNorm>,
    /// The defuzzifier.
    pub defuzzifier: Option<Defuzzifier>,
    /// Value when nothing fired.
    pub default: f64,
    /// Keep the previous value when nothing fired.
    pub lock_previous: bool,
    /// Terms.
    pub terms: Vec<Term>,
}

impl OutputVariable {
    /// An enabled output variable without terms, aggregation or defuzzifier, over an unbounded range, defaulting to
    /// NaN (fuzzylite's defaults).
    pub fn new(name: impl Into<String>) -> Self {
        Self {
            name: name.into(),
            description: String::new(),
            enabled: true,
            minimum: f64::NEG_INFINITY,
            maximum: f64::INFINITY,
            lock_range: false,
            aggregation: None,
            defuzzifier: None,
            default: f64::NAN,
            lock_previous: false,
            terms: vec![],
        }
    }
}

impl PartialEq for OutputVariable {
    fn eq(&self, o: &Self) -> bool {
        // Defaults are often NaN: equal when both are NaN.
        let same = |a: f64, b: f64| a == b || (a.is_nan() && b.is_nan());
        self.name == o.name
            && self.description == o.description
            && self.enabled == o.enabled
            && same(self.minimum, o.minimum)
            && same(self.maximum, o.maximum)
            && self.lock_range == o.lock_range
            && self.aggregation == o.aggregation
            && self.defuzzifier == o.defuzzifier
            && same(self.default, o.default)
            && self.lock_previous == o.lock_previous
            && self.terms == o.terms
    }
}

/// Comparison of the Threshold activation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[allow(missing_docs)]
pub enum Comparison {
    LessThan,
    LessThanOrEqualTo,
    EqualTo,
    NotEqualTo,
    GreaterThanOrEqualTo,
    GreaterThan,
}

impl Comparison {
    /// The operator as written in FLL.
    pub fn symbol(self) -> &'static str {
        match self {
            Comparison::LessThan => "<",
            Comparison::LessThanOrEqualTo => "<=",
            Comparison::EqualTo => "==",
            Comparison::NotEqualTo => "!=",
            Comparison::GreaterThanOrEqualTo => ">=",
            Comparison::GreaterThan => ">",
        }
    }

    /// The comparison written `s`.
    pub fn from_symbol(s: &str) -> Option<Self> {
        [
            Comparison::LessThan,
            Comparison::LessThanOrEqualTo,
            Comparison::EqualTo,
            Comparison::NotEqualTo,
            Comparison::GreaterThanOrEqualTo,
            Comparison::GreaterThan,
        ]
        .into_iter()
        .find(|c| c.symbol() == s)
    }

    fn holds(self, a: f64, b: f64) -> bool {
        match self {
            Comparison::LessThan => is_lt(a, b),
            Comparison::LessThanOrEqualTo => is_le(a, b),
            Comparison::EqualTo => is_eq(a, b),
            Comparison::NotEqualTo => !is_eq(a, b),
            Comparison::GreaterThanOrEqualTo => is_ge(a, b),
            Comparison::GreaterThan => is_gt(a, b),
        }
    }
}

/// Which rules of a block fire.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Activation {
    /// Every rule.
    General,
    /// The first `rules` rules (in order) with a degree of at least `threshold`.
    First {
        /// How many.
        rules: usize,
        /// Least degree.
        threshold: f64,
    },
    /// The last `rules` rules with a degree of at least `threshold`.
    Last {
        /// How many.
        rules: usize,
        /// Least degree.
        threshold: f64,
    },
    /// The `rules` rules of highest degree.
    Highest {
        /// How many.
        rules: usize,
    },
    /// The `rules` rules of lowest non-zero degree.
    Lowest {
        /// How many.
        rules: usize,
    },
    /// Rules whose degree compares true with `value`.
    Threshold {
        /// The comparison.
        comparison: Comparison,
        /// The value compared with.
        value: f64,
    },
    /// Every rule, degrees divided by their sum.
    Proportional,
}

impl Activation {
    /// FLL text (`Highest 2`, `Threshold >= 0.5`).
    pub fn to_fll(&self) -> String {
        use crate::term::fmt_num;
        match self {
            Activation::General => "General".into(),
            Activation::First { rules, threshold } => {
                format!("First {rules} {}", fmt_num(*threshold))
            }
            Activation::Last { rules, threshold } => {
                format!("Last {rules} {}", fmt_num(*threshold))
            }
            Activation::Highest { rules } => format!("Highest {rules}"),
            Activation::Lowest { rules } => format!("Lowest {rules}"),
            Activation::Threshold { comparison, value } => {
                format!("Threshold {} {}", comparison.symbol(), fmt_num(*value))
            }
            Activation::Proportional => "Proportional".into(),
        }
    }

    /// Parses the FLL text of an activation.
    pub fn from_fll(text: &str) -> Result<Activation, FuzzyError> {
        let t: Vec<&str> = text.split_whitespace().collect();
        let count = |i: usize| -> Result<usize, FuzzyError> {
            match t.get(i) {
                None => Ok(1),
                Some(s) => crate::expr::parse_number(s)
                    .filter(|v| v.fract() == 0.0 && *v >= 0.0 && *v < 1e9)
                    .map(|v| v as usize)
                    .ok_or_else(|| {
                        FuzzyError::syntax(
                            0,
                            format!("activation {}: '{s}' is not a number of rules", t[0]),
                        )
                    }),
            }
        };
        let number = |i: usize, default: f64| -> Result<f64, FuzzyError> {
            match t.get(i) {
                None => Ok(default),
                Some(s) => crate::expr::parse_number(s).ok_or_else(|| {
                    FuzzyError::syntax(0, format!("activation {}: '{s}' is not a number", t[0]))
                }),
            }
        };
        let max_params = |n: usize| -> Result<(), FuzzyError> {
            if t.len() > n + 1 {
                Err(FuzzyError::syntax(
                    0,
                    format!("activation {} takes at most {n} parameters", t[0]),
                ))
            } else {
                Ok(())
            }
        };
        let Some(&name) = t.first() else {
            return Err(FuzzyError::syntax(0, "empty activation"));
        };
        Ok(match name {
            "General" => {
                max_params(0)?;
                Activation::General
            }
            "Proportional" => {
                max_params(0)?;
                Activation::Proportional
            }
            "First" => {
                max_params(2)?;
                Activation::First {
                    rules: count(1)?,
                    threshold: number(2, 0.0)?,
                }
            }
            "Last" => {
                max_params(2)?;
                Activation::Last {
                    rules: count(1)?,
                    threshold: number(2, 0.0)?,
                }
            }
            "Highest" => {
                max_params(1)?;
                Activation::Highest { rules: count(1)? }
            }
            "Lowest" => {
                max_params(1)?;
                Activation::Lowest { rules: count(1)? }
            }
            "Threshold" => {
                max_params(2)?;
                let comparison = match t.get(1) {
                    None => Comparison::GreaterThanOrEqualTo,
                    Some(s) => Comparison::from_symbol(s).ok_or_else(|| {
                        FuzzyError::syntax(0, format!("activation Threshold: unknown comparison '{s}' (use < <= == != >= >)"))
                    })?,
                };
                Activation::Threshold {
                    comparison,
                    value: number(2, 0.0)?,
                }
            }
            other => {
                return Err(FuzzyError::syntax(
                    0,
                    format!("unknown activation '{other}'"),
                ));
            }
        })
    }
}

/// A rule block.
#[derive(Debug, Clone, PartialEq)]
pub struct RuleBlock {
    /// Name.
    pub name: String,
    /// Free text.
    pub description: String,
    /// Disabled blocks do not fire.
    pub enabled: bool,
    /// Operator of `and`.
    pub conjunction: Option<TNorm>,
    /// Operator of `or`.
    pub disjunction: Option<SNorm>,
    /// Operator shaping each conclusion's term by the rule's degree.
    pub implication: Option<TNorm>,
    /// Which rules fire (`None`: General).
    pub activation: Option<Activation>,
    /// The rules.
    pub rules: Vec<Rule>,
}

impl RuleBlock {
    /// An enabled rule block without operators or rules (General activation).
    pub fn new(name: impl Into<String>) -> Self {
        Self {
            name: name.into(),
            description: String::new(),
            enabled: true,
            conjunction: None,
            disjunction: None,
            implication: None,
            activation: None,
            rules: vec![],
        }
    }
}

/// A rule as text, compiled when the engine loads.
#[derive(Debug, Clone)]
pub struct Rule {
    /// The text, `if ... then ... [with w]`.
    pub text: String,
    /// Line of the text in its file (0 when not from a file).
    pub line: usize,
    compiled: Option<Compiled>,
}

impl PartialEq for Rule {
    fn eq(&self, other: &Self) -> bool {
        self.text == other.text
    }
}

impl Rule {
    /// A rule from its text (compiled by [`Engine::load`]).
    pub fn new(text: impl Into<String>, line: usize) -> Self {
        Self {
            text: text.into(),
            line,
            compiled: None,
        }
    }
}

#[derive(Debug, Clone)]
struct Compiled {
    weight: f64,
    antecedent: Node,
    conclusions: Vec<Conclusion>,
}

#[derive(Debug, Clone)]
enum Node {
    Prop {
        var: VarRef,
        hedges: Vec<Hedge>,
        term: Option<usize>,
    },
    And(Box<Node>, Box<Node>),
    Or(Box<Node>, Box<Node>),
}

#[derive(Debug, Clone)]
struct Conclusion {
    output: usize,
    hedges: Vec<Hedge>,
    term: usize,
}

#[derive(Debug, Clone, Copy)]
struct Activated {
    term: usize,
    degree: f64,
    implication: Option<TNorm>,
}

/// Per-evaluation state, sized once when the engine loads.
#[derive(Debug, Clone, Default)]
struct State {
    inputs: Vec<f64>,
    outputs: Vec<f64>,
    previous: Vec<f64>,
    fuzzy: Vec<Vec<Activated>>,
    degrees: Vec<Vec<f64>>,
    order: Vec<usize>,
    groups: Vec<(usize, f64)>,
}

/// A fuzzy inference engine.
#[derive(Debug, Clone)]
pub struct Engine {
    /// Name.
    pub name: String,
    /// Free text.
    pub description: String,
    /// Input variables.
    pub inputs: Vec<InputVariable>,
    /// Output variables.
    pub outputs: Vec<OutputVariable>,
    /// Rule blocks.
    pub blocks: Vec<RuleBlock>,
    state: State,
    loaded: bool,
}

impl PartialEq for Engine {
    fn eq(&self, other: &Self) -> bool {
        self.name == other.name
            && self.description == other.description
            && self.inputs == other.inputs
            && self.outputs == other.outputs
            && self.blocks == other.blocks
    }
}

/// Deepest nesting of parentheses in a rule.
const MAX_RULE_DEPTH: usize = 64;

impl Engine {
    /// An empty engine (add variables and blocks, then [`Engine::load`]).
    pub fn new(name: impl Into<String>) -> Self {
        Self {
            name: name.into(),
            description: String::new(),
            inputs: vec![],
            outputs: vec![],
            blocks: vec![],
            state: State::default(),
            loaded: false,
        }
    }

    /// Index of the input variable `name`.
    pub fn input_index(&self, name: &str) -> Option<usize> {
        self.inputs.iter().position(|v| v.name == name)
    }

    /// Index of the output variable `name`.
    pub fn output_index(&self, name: &str) -> Option<usize> {
        self.outputs.iter().position(|v| v.name == name)
    }

    fn resolve(&self, name: &str) -> Option<VarRef> {
        self.input_index(name)
            .map(VarRef::Input)
            .or_else(|| self.output_index(name).map(VarRef::Output))
    }

    /// Checks the engine, compiles its Function terms and rules, and sizes every buffer. Must be called after
    /// changing variables, terms or rules and before [`Engine::process`].
    pub fn load(&mut self) -> Result<(), FuzzyError> {
        self.loaded = false;
        let mut names = std::collections::HashSet::new();
        for name in self
            .inputs
            .iter()
            .map(|v| &v.name)
            .chain(self.outputs.iter().map(|v| &v.name))
        {
            if !valid_name(name) {
                return Err(FuzzyError::Invalid(format!(
                    "variable name '{name}' must be letters, digits, '_' or '.'"
                )));
            }
            if !names.insert(name.clone()) {
                return Err(FuzzyError::Invalid(format!(
                    "two variables are called '{name}'"
                )));
            }
        }
        let check_terms =
            |var: &str, terms: &[Term], min: f64, max: f64| -> Result<(), FuzzyError> {
                if min.is_nan() || max.is_nan() || min > max {
                    return Err(FuzzyError::Invalid(format!(
                        "variable '{var}': range {min} {max} is not an interval"
                    )));
                }
                // Two terms may share a name (fuzzylite allows it); rules then refer to the first.
                for t in terms {
                    if !valid_name(&t.name) {
                        return Err(FuzzyError::Invalid(format!(
                            "variable '{var}': term name '{}' is not valid",
                            t.name
                        )));
                    }
                }
                Ok(())
            };
        for v in &self.inputs {
            check_terms(&v.name, &v.terms, v.minimum, v.maximum)?;
        }
        for v in &self.outputs {
            check_terms(&v.name, &v.terms, v.minimum, v.maximum)?;
            match v.defuzzifier {
                None => {
                    return Err(FuzzyError::Invalid(format!(
                        "output '{}' has no defuzzifier",
                        v.name
                    )));
                }
                Some(d) if d.is_integral() && v.aggregation.is_none() => {
                    return Err(FuzzyError::Invalid(format!(
                        "output '{}' uses {} but has no aggregation operator",
                        v.name,
                        d.name()
                    )));
                }
                _ => {}
            }
        }
        // Function terms.
        let resolver = |n: &str| self.resolve(n);
        let mut compiled_inputs = self.inputs.clone();
        let mut compiled_outputs = self.outputs.clone();
        for (vi, v) in compiled_inputs.iter_mut().enumerate() {
            for t in &mut v.terms {
                t.shape.compile(&resolver).map_err(|e| {
                    describe(
                        e,
                        &format!("input '{}' term '{}'", self.inputs[vi].name, t.name),
                    )
                })?;
            }
        }
        for (vo, v) in compiled_outputs.iter_mut().enumerate() {
            for t in &mut v.terms {
                t.shape.compile(&resolver).map_err(|e| {
                    describe(
                        e,
                        &format!("output '{}' term '{}'", self.outputs[vo].name, t.name),
                    )
                })?;
                if let Shape::Function {
                    compiled: Some(e), ..
                } = &t.shape
                {
                    let mut recursive = false;
                    e.visit_vars(&mut |r| recursive |= r == VarRef::Output(vo));
                    if recursive {
                        return Err(FuzzyError::Invalid(format!(
                            "output '{}' term '{}': recursive Function (the formula reads the variable it defines)",
                            v.name, t.name
                        )));
                    }
                }
            }
        }
        self.inputs = compiled_inputs;
        self.outputs = compiled_outputs;
        // Rules.
        let mut blocks = self.blocks.clone();
        for b in &mut blocks {
            let header = RuleBlock {
                rules: vec![],
                ..b.clone()
            };
            for r in &mut b.rules {
                let c = self
                    .compile_rule(&r.text, &header)
                    .map_err(|e| e.at_line(r.line))?;
                r.compiled = Some(c);
            }
        }
        self.blocks = blocks;
        let max_terms = self
            .outputs
            .iter()
            .map(|o| o.terms.len())
            .max()
            .unwrap_or(0);
        let max_rules = self.blocks.iter().map(|b| b.rules.len()).max().unwrap_or(0);
        let conclusions: Vec<usize> = (0..self.outputs.len())
            .map(|o| {
                self.blocks
                    .iter()
                    .flat_map(|b| &b.rules)
                    .filter_map(|r| r.compiled.as_ref())
                    .map(|c| c.conclusions.iter().filter(|k| k.output == o).count())
                    .sum()
            })
            .collect();
        self.state = State {
            inputs: vec![f64::NAN; self.inputs.len()],
            outputs: vec![f64::NAN; self.outputs.len()],
            previous: vec![f64::NAN; self.outputs.len()],
            fuzzy: conclusions.iter().map(|&n| Vec::with_capacity(n)).collect(),
            degrees: self
                .blocks
                .iter()
                .map(|b| vec![0.0; b.rules.len()])
                .collect(),
            order: Vec::with_capacity(max_rules),
            groups: Vec::with_capacity(max_terms),
        };
        self.loaded = true;
        Ok(())
    }

    fn compile_rule(&self, text: &str, block: &RuleBlock) -> Result<Compiled, FuzzyError> {
        let text = text.split('#').next().unwrap_or("");
        let spaced = text.replace('(', " ( ").replace(')', " ) ");
        let tokens: Vec<&str> = spaced.split_whitespace().collect();
        if tokens.first() != Some(&"if") {
            return Err(FuzzyError::syntax(
                0,
                format!("rule must start with 'if': {text}"),
            ));
        }
        let then = tokens.iter().position(|t| *t == "then").ok_or_else(|| {
            FuzzyError::syntax(0, format!("keyword 'then' not found in rule: {text}"))
        })?;
        let with = tokens.iter().position(|t| *t == "with");
        let (consequent, weight) = match with {
            Some(w) if w > then => {
                let weight_tok = tokens
                    .get(w + 1)
                    .ok_or_else(|| FuzzyError::syntax(0, "expected a number after 'with'"))?;
                if tokens.len() > w + 2 {
                    return Err(FuzzyError::syntax(
                        0,
                        format!("unexpected '{}' at the end of the rule", tokens[w + 2]),
                    ));
                }
                let weight = crate::expr::parse_number(weight_tok).ok_or_else(|| {
                    FuzzyError::syntax(0, format!("rule weight '{weight_tok}' is not a number"))
                })?;
                (&tokens[then + 1..w], weight)
            }
            _ => (&tokens[then + 1..], 1.0),
        };
        let ante = &tokens[1..then];
        if ante.is_empty() {
            return Err(FuzzyError::syntax(
                0,
                "the rule has no condition between 'if' and 'then'",
            ));
        }
        let mut pos = 0;
        let antecedent = self.parse_or(ante, &mut pos, 0)?;
        if pos != ante.len() {
            return Err(FuzzyError::syntax(
                0,
                format!("unexpected '{}' in the condition", ante[pos]),
            ));
        }
        let mut uses = (false, false);
        uses_ops(&antecedent, &mut uses);
        if uses.0 && block.conjunction.is_none() {
            return Err(FuzzyError::syntax(
                0,
                format!(
                    "rule uses 'and' but rule block '{}' has no conjunction",
                    block.name
                ),
            ));
        }
        if uses.1 && block.disjunction.is_none() {
            return Err(FuzzyError::syntax(
                0,
                format!(
                    "rule uses 'or' but rule block '{}' has no disjunction",
                    block.name
                ),
            ));
        }
        let conclusions = self.parse_consequent(consequent)?;
        for c in &conclusions {
            let out = &self.outputs[c.output];
            if out.defuzzifier.is_some_and(|d| d.is_integral()) && block.implication.is_none() {
                return Err(FuzzyError::syntax(
                    0,
                    format!(
                        "rule concludes on '{}' ({}) but rule block '{}' has no implication",
                        out.name,
                        out.defuzzifier.map_or("", |d| d.name()),
                        block.name
                    ),
                ));
            }
        }
        Ok(Compiled {
            weight,
            antecedent,
            conclusions,
        })
    }

    fn parse_or(&self, t: &[&str], pos: &mut usize, depth: usize) -> Result<Node, FuzzyError> {
        let mut lhs = self.parse_and(t, pos, depth)?;
        while t.get(*pos) == Some(&"or") {
            *pos += 1;
            let rhs = self.parse_and(t, pos, depth)?;
            lhs = Node::Or(Box::new(lhs), Box::new(rhs));
        }
        Ok(lhs)
    }

    fn parse_and(&self, t: &[&str], pos: &mut usize, depth: usize) -> Result<Node, FuzzyError> {
        let mut lhs = self.parse_atom(t, pos, depth)?;
        while t.get(*pos) == Some(&"and") {
            *pos += 1;
            let rhs = self.parse_atom(t, pos, depth)?;
            lhs = Node::And(Box::new(lhs), Box::new(rhs));
        }
        Ok(lhs)
    }

    fn parse_atom(&self, t: &[&str], pos: &mut usize, depth: usize) -> Result<Node, FuzzyError> {
        if depth > MAX_RULE_DEPTH {
            return Err(FuzzyError::syntax(
                0,
                format!("rule nested deeper than {MAX_RULE_DEPTH} parentheses"),
            ));
        }
        match t.get(*pos) {
            Some(&"(") => {
                *pos += 1;
                let n = self.parse_or(t, pos, depth + 1)?;
                if t.get(*pos) != Some(&")") {
                    return Err(FuzzyError::syntax(0, "missing ')' in the condition"));
                }
                *pos += 1;
                Ok(n)
            }
            Some(name) => {
                let var = self.resolve(name).ok_or_else(|| {
                    FuzzyError::syntax(0, format!("unknown variable '{name}' in the condition"))
                })?;
                *pos += 1;
                if t.get(*pos) != Some(&"is") {
                    return Err(FuzzyError::syntax(
                        0,
                        format!("expected 'is' after '{name}'"),
                    ));
                }
                *pos += 1;
                let mut hedges = Vec::new();
                loop {
                    let Some(tok) = t.get(*pos) else {
                        return Err(FuzzyError::syntax(
                            0,
                            format!("expected a hedge or term after '{name} is'"),
                        ));
                    };
                    *pos += 1;
                    if let Some(h) = Hedge::from_keyword(tok) {
                        hedges.push(h);
                        if h == Hedge::Any {
                            return Ok(Node::Prop {
                                var,
                                hedges,
                                term: None,
                            });
                        }
                        continue;
                    }
                    let terms = match var {
                        VarRef::Input(i) => &self.inputs[i].terms,
                        VarRef::Output(o) => &self.outputs[o].terms,
                        VarRef::X => return Err(FuzzyError::syntax(0, "x is not a variable")),
                    };
                    let term = terms.iter().position(|x| x.name == *tok).ok_or_else(|| {
                        FuzzyError::syntax(0, format!("variable '{name}' has no term '{tok}'"))
                    })?;
                    return Ok(Node::Prop {
                        var,
                        hedges,
                        term: Some(term),
                    });
                }
            }
            None => Err(FuzzyError::syntax(0, "the condition ends too early")),
        }
    }

    fn parse_consequent(&self, t: &[&str]) -> Result<Vec<Conclusion>, FuzzyError> {
        if t.is_empty() {
            return Err(FuzzyError::syntax(
                0,
                "the rule has no conclusion after 'then'",
            ));
        }
        let mut out = Vec::new();
        let mut pos = 0;
        loop {
            let name = t[pos];
            let output = self.output_index(name).ok_or_else(|| {
                FuzzyError::syntax(
                    0,
                    format!("'{name}' after 'then' is not an output variable"),
                )
            })?;
            pos += 1;
            if t.get(pos) != Some(&"is") {
                return Err(FuzzyError::syntax(
                    0,
                    format!("expected 'is' after '{name}'"),
                ));
            }
            pos += 1;
            let mut hedges = Vec::new();
            let term = loop {
                let Some(tok) = t.get(pos) else {
                    return Err(FuzzyError::syntax(
                        0,
                        format!("expected a term after '{name} is'"),
                    ));
                };
                pos += 1;
                match Hedge::from_keyword(tok) {
                    Some(Hedge::Any) => {
                        return Err(FuzzyError::syntax(0, "'any' cannot be concluded"));
                    }
                    Some(h) => hedges.push(h),
                    None => {
                        break self.outputs[output]
                            .terms
                            .iter()
                            .position(|x| x.name == *tok)
                            .ok_or_else(|| {
                                FuzzyError::syntax(
                                    0,
                                    format!("output '{name}' has no term '{tok}'"),
                                )
                            })?;
                    }
                }
            };
            out.push(Conclusion {
                output,
                hedges,
                term,
            });
            match t.get(pos) {
                None => return Ok(out),
                Some(&"and") if pos + 1 < t.len() => pos += 1,
                Some(other) => {
                    return Err(FuzzyError::syntax(
                        0,
                        format!("expected 'and' or 'with', found '{other}'"),
                    ));
                }
            }
        }
    }

    /// Sets input `i` (clamped into its range when lock-range is on). Out-of-range indices are ignored.
    pub fn set_input(&mut self, i: usize, value: f64) {
        if let (Some(v), Some(slot)) = (self.inputs.get(i), self.state.inputs.get_mut(i)) {
            *slot = if v.lock_range {
                bound(value, v.minimum, v.maximum)
            } else {
                value
            };
        }
    }

    /// Sets the input called `name`.
    pub fn set_input_by_name(&mut self, name: &str, value: f64) -> Result<(), FuzzyError> {
        let i = self
            .input_index(name)
            .ok_or_else(|| FuzzyError::Invalid(format!("no input variable '{name}'")))?;
        self.set_input(i, value);
        Ok(())
    }

    /// Current value of input `i` (NaN when unset or out of range).
    pub fn input_value(&self, i: usize) -> f64 {
        self.state.inputs.get(i).copied().unwrap_or(f64::NAN)
    }

    /// Value of output `k` after [`Engine::process`] (NaN when out of range).
    pub fn output_value(&self, k: usize) -> f64 {
        self.state.outputs.get(k).copied().unwrap_or(f64::NAN)
    }

    /// Value of the output called `name`.
    pub fn output_by_name(&self, name: &str) -> Option<f64> {
        self.output_index(name).map(|k| self.output_value(k))
    }

    /// Forgets input values, output values and previous values.
    pub fn restart(&mut self) {
        self.state.inputs.iter_mut().for_each(|v| *v = f64::NAN);
        self.state.outputs.iter_mut().for_each(|v| *v = f64::NAN);
        self.state.previous.iter_mut().for_each(|v| *v = f64::NAN);
        self.state.fuzzy.iter_mut().for_each(Vec::clear);
    }

    /// Runs one inference with the current inputs. Fails only when the engine was not loaded.
    pub fn process(&mut self) -> Result<(), FuzzyError> {
        if !self.loaded {
            return Err(FuzzyError::Invalid(
                "engine not loaded: call load() after building or changing it".into(),
            ));
        }
        {
            let State {
                inputs,
                outputs,
                fuzzy,
                degrees,
                order,
                ..
            } = &mut self.state;
            fuzzy.iter_mut().for_each(Vec::clear);
            for (b, block) in self.blocks.iter().enumerate() {
                if block.enabled {
                    let parts = Parts {
                        inputs,
                        outputs,
                        fuzzy,
                        order,
                    };
                    activate(block, &mut degrees[b], &self.inputs, &self.outputs, parts);
                }
            }
        }
        for k in 0..self.outputs.len() {
            defuzzify_output(k, &self.outputs, &mut self.state);
        }
        Ok(())
    }
}

fn describe(e: FuzzyError, what: &str) -> FuzzyError {
    match e {
        FuzzyError::Syntax { line, message } => FuzzyError::Syntax {
            line,
            message: format!("{what}: {message}"),
        },
        FuzzyError::Invalid(m) => FuzzyError::Invalid(format!("{what}: {m}")),
    }
}

/// Names as fuzzylite accepts them: letters, digits, `_` and `.`.
pub fn valid_name(s: &str) -> bool {
    !s.is_empty()
        && s.chars()
            .all(|c| c.is_alphanumeric() || c == '_' || c == '.')
}

fn uses_ops(n: &Node, uses: &mut (bool, bool)) {
    match n {
        Node::Prop { .. } => {}
        Node::And(a, b) => {
            uses.0 = true;
            uses_ops(a, uses);
            uses_ops(b, uses);
        }
        Node::Or(a, b) => {
            uses.1 = true;
            uses_ops(a, uses);
            uses_ops(b, uses);
        }
    }
}

/// The parts of the state rule activation touches (split borrows).
struct Parts<'a> {
    inputs: &'a [f64],
    outputs: &'a [f64],
    fuzzy: &'a mut [Vec<Activated>],
    order: &'a mut Vec<usize>,
}

fn antecedent_degree(
    n: &Node,
    block: &RuleBlock,
    in_vars: &[InputVariable],
    out_vars: &[OutputVariable],
    p: &Parts<'_>,
) -> f64 {
    match n {
        Node::Prop { var, hedges, term } => {
            let enabled = match var {
                VarRef::Input(i) => in_vars[*i].enabled,
                VarRef::Output(o) => out_vars[*o].enabled,
                VarRef::X => false,
            };
            if !enabled {
                return 0.0;
            }
            if hedges.last() == Some(&Hedge::Any) {
                let mut r = Hedge::Any.apply(f64::NAN);
                for h in hedges.iter().rev().skip(1) {
                    r = h.apply(r);
                }
                return r;
            }
            let Some(t) = *term else { return f64::NAN };
            let mut r = match var {
                VarRef::Input(i) => {
                    in_vars[*i].terms[t]
                        .shape
                        .membership(p.inputs[*i], p.inputs, p.outputs)
                }
                VarRef::Output(o) => {
                    let agg = out_vars[*o].aggregation;
                    let mut d = 0.0;
                    for a in p.fuzzy[*o].iter().filter(|a| a.term == t) {
                        d = match agg {
                            Some(s) => s.compute(d, a.degree),
                            None => d + a.degree,
                        };
                    }
                    d
                }
                VarRef::X => f64::NAN,
            };
            for h in hedges.iter().rev() {
                r = h.apply(r);
            }
            r
        }
        Node::And(a, b) => {
            let (x, y) = (
                antecedent_degree(a, block, in_vars, out_vars, p),
                antecedent_degree(b, block, in_vars, out_vars, p),
            );
            block.conjunction.map_or(f64::NAN, |t| t.compute(x, y))
        }
        Node::Or(a, b) => {
            let (x, y) = (
                antecedent_degree(a, block, in_vars, out_vars, p),
                antecedent_degree(b, block, in_vars, out_vars, p),
            );
            block.disjunction.map_or(f64::NAN, |s| s.compute(x, y))
        }
    }
}

fn trigger(
    c: &Compiled,
    degree: f64,
    block: &RuleBlock,
    out_vars: &[OutputVariable],
    p: &mut Parts<'_>,
) {
    if !is_gt(degree, 0.0) {
        return;
    }
    // As in fuzzylite, a conclusion's hedges change the degree passed on to the conclusions after it.
    let mut d = degree;
    for k in &c.conclusions {
        if !out_vars[k.output].enabled {
            continue;
        }
        for h in k.hedges.iter().rev() {
            d = h.apply(d);
        }
        p.fuzzy[k.output].push(Activated {
            term: k.term,
            degree: d,
            implication: block.implication,
        });
    }
}

fn activate(
    block: &RuleBlock,
    degrees: &mut [f64],
    in_vars: &[InputVariable],
    out_vars: &[OutputVariable],
    mut p: Parts<'_>,
) {
    let degree_of = |r: &Rule, p: &Parts<'_>| -> f64 {
        r.compiled.as_ref().map_or(0.0, |c| {
            c.weight * antecedent_degree(&c.antecedent, block, in_vars, out_vars, p)
        })
    };
    match block.activation.unwrap_or(Activation::General) {
        Activation::General => {
            for (i, r) in block.rules.iter().enumerate() {
                let d = degree_of(r, &p);
                degrees[i] = d;
                if let Some(c) = &r.compiled {
                    trigger(c, d, block, out_vars, &mut p);
                }
            }
        }
        Activation::First { rules, threshold } | Activation::Last { rules, threshold } => {
            let reverse = matches!(block.activation, Some(Activation::Last { .. }));
            let n = block.rules.len();
            let mut fired = 0;
            for j in 0..n {
                let i = if reverse { n - 1 - j } else { j };
                let r = &block.rules[i];
                let d = degree_of(r, &p);
                degrees[i] = d;
                if fired < rules && is_gt(d, 0.0) && is_ge(d, threshold) {
                    if let Some(c) = &r.compiled {
                        trigger(c, d, block, out_vars, &mut p);
                    }
                    fired += 1;
                }
            }
        }
        Activation::Highest { rules } | Activation::Lowest { rules } => {
            let highest = matches!(block.activation, Some(Activation::Highest { .. }));
            p.order.clear();
            for (i, r) in block.rules.iter().enumerate() {
                let d = degree_of(r, &p);
                degrees[i] = d;
                if is_gt(d, 0.0) {
                    p.order.push(i);
                }
            }
            if highest {
                p.order.sort_by(|&a, &b| degrees[b].total_cmp(&degrees[a]));
            } else {
                p.order.sort_by(|&a, &b| degrees[a].total_cmp(&degrees[b]));
            }
            let count = rules.min(p.order.len());
            for j in 0..count {
                let i = p.order[j];
                if let Some(c) = &block.rules[i].compiled {
                    trigger(c, degrees[i], block, out_vars, &mut p);
                }
            }
        }
        Activation::Threshold { comparison, value } => {
            for (i, r) in block.rules.iter().enumerate() {
                let d = degree_of(r, &p);
                degrees[i] = d;
                if comparison.holds(d, value) {
                    if let Some(c) = &r.compiled {
                        trigger(c, d, block, out_vars, &mut p);
                    }
                }
            }
        }
        Activation::Proportional => {
            let mut sum = 0.0;
            for (i, r) in block.rules.iter().enumerate() {
                let d = degree_of(r, &p);
                degrees[i] = d;
                sum += d;
            }
            for (i, r) in block.rules.iter().enumerate() {
                let d = degrees[i] / sum;
                degrees[i] = d;
                if let Some(c) = &r.compiled {
                    trigger(c, d, block, out_vars, &mut p);
                }
            }
        }
    }
}

fn defuzzify_output(k: usize, out_vars: &[OutputVariable], st: &mut State) {
    let var = &out_vars[k];
    if !var.enabled {
        return;
    }
    if st.outputs[k].is_finite() {
        st.previous[k] = st.outputs[k];
    }
    let result = if st.fuzzy[k].is_empty() {
        None
    } else {
        var.defuzzifier.and_then(|d| {
            defuzzify(
                d,
                var,
                &st.fuzzy[k],
                &st.inputs,
                &st.outputs,
                &mut st.groups,
            )
        })
    };
    let value = match result {
        Some(v) => v,
        None if var.lock_previous && !st.previous[k].is_nan() => st.previous[k],
        None => var.default,
    };
    st.outputs[k] = if var.lock_range {
        bound(value, var.minimum, var.maximum)
    } else {
        value
    };
}

/// The aggregated membership at x; `None` when an activated term lacks an implication.
fn aggregated(
    var: &OutputVariable,
    fuzzy: &[Activated],
    x: f64,
    inputs: &[f64],
    outputs: &[f64],
) -> Option<f64> {
    let agg = var.aggregation?;
    let mut mu = 0.0;
    for a in fuzzy {
        let m = var.terms[a.term].shape.membership(x, inputs, outputs);
        mu = agg.compute(mu, a.implication?.compute(m, a.degree));
    }
    Some(mu)
}

fn defuzzify(
    d: Defuzzifier,
    var: &OutputVariable,
    fuzzy: &[Activated],
    inputs: &[f64],
    outputs: &[f64],
    groups: &mut Vec<(usize, f64)>,
) -> Option<f64> {
    let (lo, hi) = (var.minimum, var.maximum);
    let sample = |res: usize, i: usize| lo + (i as f64 + 0.5) * ((hi - lo) / res as f64);
    let mu = |x: f64| aggregated(var, fuzzy, x, inputs, outputs);
    match d {
        Defuzzifier::Centroid(res) => {
            if !(lo + hi).is_finite() {
                return Some(f64::NAN);
            }
            let (mut area, mut centroid) = (0.0, 0.0);
            for i in 0..res {
                let x = sample(res, i);
                let y = mu(x)?;
                centroid += y * x;
                area += y;
            }
            Some(centroid / area)
        }
        Defuzzifier::Bisector(res) => {
            // Areas grown from both ends towards the middle (fuzzylite 6).
            if !(lo + hi).is_finite() {
                return Some(f64::NAN);
            }
            let dx = (hi - lo) / res as f64;
            let (mut left, mut right) = (0usize, 0usize);
            let (mut left_area, mut right_area) = (0.0, 0.0);
            let (mut x_left, mut x_right) = (lo, hi);
            for _ in 0..res {
                if is_le(left_area, right_area) {
                    x_left = lo + (left as f64 + 0.5) * dx;
                    left_area += mu(x_left)?;
                    left += 1;
                } else {
                    x_right = hi - (right as f64 + 0.5) * dx;
                    right_area += mu(x_right)?;
                    right += 1;
                }
            }
            Some((left_area * x_right + right_area * x_left) / (left_area + right_area))
        }
        Defuzzifier::SmallestOfMaximum(res)
        | Defuzzifier::LargestOfMaximum(res)
        | Defuzzifier::MeanOfMaximum(res) => {
            // fuzzylite 6 semantics, which the reference tables were computed with: tolerant comparisons, and the
            // mean of maximum is the middle of the first plateau of maximum membership.
            if !(lo + hi).is_finite() {
                return Some(f64::NAN);
            }
            let mut ymax = -1.0;
            match d {
                Defuzzifier::SmallestOfMaximum(_) => {
                    let mut smallest = lo;
                    for i in 0..res {
                        let x = sample(res, i);
                        let y = mu(x)?;
                        if is_gt(y, ymax) {
                            smallest = x;
                            ymax = y;
                        }
                    }
                    Some(smallest)
                }
                Defuzzifier::LargestOfMaximum(_) => {
                    let mut largest = hi;
                    for i in 0..res {
                        let x = sample(res, i);
                        let y = mu(x)?;
                        if is_ge(y, ymax) {
                            largest = x;
                            ymax = y;
                        }
                    }
                    Some(largest)
                }
                _ => {
                    let (mut first, mut last, mut same_plateau) = (lo, hi, false);
                    for i in 0..res {
                        let x = sample(res, i);
                        let y = mu(x)?;
                        if is_gt(y, ymax) {
                            ymax = y;
                            first = x;
                            last = x;
                            same_plateau = true;
                        } else if is_eq(y, ymax) && same_plateau {
                            last = x;
                        } else if is_lt(y, ymax) {
                            same_plateau = false;
                        }
                    }
                    Some((first + last) / 2.0)
                }
            }
        }
        Defuzzifier::WeightedAverage(t) | Defuzzifier::WeightedSum(t) => {
            // Group activations of the same term (aggregation, or a plain sum), in order of first appearance.
            groups.clear();
            for a in fuzzy {
                match groups.iter_mut().find(|g| g.0 == a.term) {
                    Some(g) => {
                        g.1 = var
                            .aggregation
                            .unwrap_or(SNorm::UnboundedSum)
                            .compute(g.1, a.degree)
                    }
                    None => groups.push((a.term, a.degree)),
                }
            }
            let kind = match t {
                WeightedType::Automatic => {
                    let shapes = fuzzy.iter().map(|a| &var.terms[a.term].shape);
                    let tsk = shapes.clone().all(Shape::is_takagi_sugeno);
                    let tsu = shapes
                        .clone()
                        .all(|s| !s.is_takagi_sugeno() && s.is_monotonic());
                    if tsk {
                        WeightedType::TakagiSugeno
                    } else if tsu {
                        WeightedType::Tsukamoto
                    } else {
                        return None;
                    }
                }
                other => other,
            };
            let (mut sum, mut weights) = (0.0, 0.0);
            for &(term, w) in groups.iter() {
                let shape = &var.terms[term].shape;
                let z = match kind {
                    WeightedType::Tsukamoto => shape.tsukamoto(w)?,
                    _ => shape.membership(w, inputs, outputs),
                };
                sum += w * z;
                weights += w;
            }
            Some(if matches!(d, Defuzzifier::WeightedSum(_)) {
                sum
            } else {
                sum / weights
            })
        }
    }
}
