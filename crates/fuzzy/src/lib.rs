//! # stripe3d-fuzzy
//!
//! A standalone fuzzy inference engine: Mamdani, Takagi-Sugeno and Tsukamoto inference with the terms, hedges,
//! norms, activation methods and defuzzifiers of fuzzylite; reads fuzzylite's FLL and IEC 61131-7 FCL, writes
//! FLL, and evaluates FLD tables. It depends on nothing of stripe3d.
//!
//! Rust has no maintained fuzzy-logic library with FLL/FCL support and fuzzylite-exact semantics, which the paper's
//! rule bases and the conformance requirement need; hence this crate, written from the published semantics and
//! checked against fuzzylite's own outputs (`tests/conformance.rs`).
//!
//! ```
//! let fll = "Engine: dimmer
//! InputVariable: Ambient
//!   range: 0 1
//!   term: DARK Triangle 0 0.25 0.5
//!   term: BRIGHT Triangle 0.5 0.75 1
//! OutputVariable: Power
//!   range: 0 1
//!   aggregation: Maximum
//!   defuzzifier: Centroid 200
//!   default: nan
//!   term: LOW Triangle 0 0.25 0.5
//!   term: HIGH Triangle 0.5 0.75 1
//! RuleBlock:
//!   implication: Minimum
//!   rule: if Ambient is DARK then Power is HIGH
//!   rule: if Ambient is BRIGHT then Power is LOW
//! ";
//! let mut engine = stripe3d_fuzzy::fll::read(fll).unwrap();
//! engine.set_input(0, 0.25);
//! engine.process().unwrap();
//! assert!((engine.output_value(0) - 0.75).abs() < 1e-9);
//! ```
#![deny(missing_docs)]

pub mod engine;
pub mod error;
pub mod expr;
pub mod fcl;
pub mod fld;
pub mod fll;
pub mod ops;
pub mod term;

pub use engine::{
    Activation, Defuzzifier, Engine, InputVariable, OutputVariable, Rule, RuleBlock, WeightedType,
};
pub use error::FuzzyError;
pub use ops::{Hedge, SNorm, TNorm};
pub use term::{Shape, Term};
