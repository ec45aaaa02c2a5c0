//! The part's surface: characterization against a reference ([`characterize`]) and the defects found in it
//! ([`detect`]).

pub mod characterize;
pub mod detect;
