//! # stripe3d-kb
//!
//! The knowledge base of stripe3d, after the paper's object-oriented knowledge base (Wu, Lee & de Silva, section
//! 3): what is known about **products** (geometry, designed features, material, tolerances, zones), **processes**
//! (capability, the defects each produces and their probable causes) and **inspection methods** (sensor, scan and
//! rule parameters, decision standards), in TOML files an engineer edits; and what is done with it:
//!
//! - [`model`]: the files, read from text and validated (contradictory or incomplete knowledge is refused with the
//!   file and entry named);
//! - [`reason`]: measured defects → verdict (accept, rework, reject, or incomplete), ranked diagnosis with certainty
//!   factors, and a readable trace;
//! - [`check`]: design assistance, problems anticipated before production;
//! - [`learn`]: cause priors and fuzzy classification parameters learned from operators' feedback;
//! - [`diff`]: what learning changed between two versions.
//!
//! No I/O here: `stripe3d-io` reads and writes the folders and keeps the inspection history. [`shipped`] is the
//! worked example in `crates/kb/knowledge/`, compiled in so `stripe3d demo` runs anywhere.
#![deny(missing_docs)]

pub mod check;
pub mod diff;
pub mod learn;
pub mod model;
pub mod reason;

pub use model::{Decision, KnowledgeBase, SourceFile};
pub use reason::{Assessment, CauseCertainty, PartFacts, assess};

use thiserror::Error;

/// What the knowledge base refuses.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum KbError {
    /// A file is not valid TOML or does not have the expected fields.
    #[error("{file}: {message}")]
    Parse {
        /// File, relative to the knowledge base.
        file: String,
        /// The parser's message (with line and column).
        message: String,
    },
    /// An entry contradicts the rest or is out of range.
    #[error("{file}: {entry}: {message}")]
    Invalid {
        /// File, relative to the knowledge base.
        file: String,
        /// The entry (`zone[1] "sealing face"`).
        entry: String,
        /// What is wrong and what to do.
        message: String,
    },
    /// A name that is not in the knowledge base.
    #[error("no {what} `{name}` in the knowledge base (known: {known})")]
    Unknown {
        /// Product, process or method.
        what: &'static str,
        /// The name asked for.
        name: String,
        /// The names it has.
        known: String,
    },
    /// Learning could not run.
    #[error("learning: {0}")]
    Learning(String),
}

macro_rules! shipped_files {
    ($($path:literal),* $(,)?) => {
        /// Paths and texts of the shipped worked example.
        pub const SHIPPED_FILES: &[(&str, &str)] = &[
            $(($path, include_str!(concat!("../knowledge/", $path)))),*
        ];
    };
}

shipped_files!(
    "kb.toml",
    "products/cast-cover.toml",
    "products/cover-plate.toml",
    "products/demo-bracket.toml",
    "products/machined-cover.toml",
    "processes/stamping.toml",
    "processes/die-casting.toml",
    "processes/injection-moulding.toml",
    "processes/machining.toml",
    "processes/welding.toml",
    "methods/stripes-11.toml",
    "methods/stripes-11-golden.toml",
);

/// The shipped worked example (products `cover-plate`, `cast-cover`, `machined-cover` and `demo-bracket`).
pub fn shipped() -> Result<KnowledgeBase, KbError> {
    let files: Vec<SourceFile> = SHIPPED_FILES
        .iter()
        .map(|(p, t)| SourceFile {
            path: (*p).to_string(),
            text: (*t).to_string(),
        })
        .collect();
    KnowledgeBase::from_files(&files)
}

impl KnowledgeBase {
    /// The knowledge base as files (for writing a new version). Comments of hand-written files are not kept: the
    /// new version's `kb.toml` names its parent, whose files stay as they were.
    pub fn to_files(&self) -> Result<Vec<SourceFile>, KbError> {
        fn ser<T: serde::Serialize>(path: String, v: &T) -> Result<SourceFile, KbError> {
            let text = toml::to_string_pretty(v).map_err(|e| KbError::Invalid {
                file: path.clone(),
                entry: "file".into(),
                message: format!("cannot be written: {e}"),
            })?;
            Ok(SourceFile { path, text })
        }
        let mut out = vec![ser("kb.toml".into(), &self.manifest)?];
        if !self.statistics.product.is_empty() {
            out.push(ser("statistics.toml".into(), &self.statistics)?);
        }
        for (n, v) in &self.products {
            out.push(ser(format!("products/{n}.toml"), v)?);
        }
        for (n, v) in &self.processes {
            out.push(ser(format!("processes/{n}.toml"), v)?);
        }
        for (n, v) in &self.methods {
            out.push(ser(format!("methods/{n}.toml"), v)?);
        }
        for (p, t) in &self.rules {
            out.push(SourceFile {
                path: p.clone(),
                text: t.clone(),
            });
        }
        Ok(out)
    }
}
